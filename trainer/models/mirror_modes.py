"""The names of test-time mirroring's modes (trainer/models/mirror_average.py), apart so the CLIs list them without
importing torch."""

# Which views each mode averages, besides the plain one. A view names its mirrors in the order they are applied to
# the input: "t" across the main diagonal, "f" left to right.
VIEWS = {"none": (), "flip": ("f",), "transpose": ("t",), "flip+transpose": ("f", "t", "tf")}
LOW = "-low"       # suffix: average the views' coarse relief only, keep the plain view's detail
LINES = "-lines"   # suffix: average the views by the sketch's strokes only, keep the plain view's open cloth
ENERGY = "-energy"  # suffix: average all of it, then scale the fine relief back to the plain view's energy
# What the modes do, for `eval --mirrors` and `export --mirrors`; each CLI adds what the mode costs there.
HELP = ("average the tactile output over mirrored views of the sketch (left to right, across the diagonal, or both: "
        "2, 2 or 4 generator passes; a -low mode averages only the coarse relief, a -lines mode only by the sketch's "
        "strokes, an -energy mode gives the fine relief back its strength; trainer/models/mirror_average.py), before "
        "any --relief gain")
MODES = {**VIEWS, **{m + s: v for m, v in VIEWS.items() if m != "none" for s in (LOW, LINES, ENERGY)}}
