"""The names of test-time mirroring's modes (trainer/models/mirror_average.py), apart so the CLIs list them without
importing torch."""

# Which views each mode averages, besides the plain one. A view names its mirrors in the order they are applied to
# the input: "t" across the main diagonal, "f" left to right.
VIEWS = {"none": (), "flip": ("f",), "transpose": ("t",), "flip+transpose": ("f", "t", "tf")}
LOW = "-low"       # suffix: average the views' coarse relief only, keep the plain view's detail
LINES = "-lines"   # suffix: average the views by the sketch's strokes only, keep the plain view's open cloth
ENERGY = "-energy"  # suffix: average all of it, then scale the fine relief back to the plain view's energy
MODES = {**VIEWS, **{m + s: v for m, v in VIEWS.items() if m != "none" for s in (LOW, LINES, ENERGY)}}
