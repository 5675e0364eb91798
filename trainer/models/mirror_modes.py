"""The names of test-time mirroring's modes (trainer/models/mirror_average.py), apart so the CLIs list them without
importing torch."""

# Which views each mode averages, besides the plain one. A view names its mirrors in the order they are applied to
# the input: "t" across the main diagonal, "f" left to right.
VIEWS = {"none": (), "flip": ("f",), "transpose": ("t",), "flip+transpose": ("f", "t", "tf")}
LOW = "-low"   # suffix: average the views' coarse relief only, keep the plain view's detail
MODES = {**VIEWS, **{m + LOW: v for m, v in VIEWS.items() if m != "none"}}
DETAIL_SIGMA_PX = 5.0   # 1.5 mm at the training grid's 0.3 mm/px; why in mirror_average.py
