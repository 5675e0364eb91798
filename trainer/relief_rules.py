"""The names of the relief calibration rules (trainer/relief.py), apart so the CLIs list them without importing
torch."""

GAIN_RULES = ("rms", "ls", "lift")               # one gain: trainer/calibration.py
# shade: the visual's own shading mixed in (trainer/shading_fit.py); shade-lift: the same, the model's weight >= 1
# auto: whichever of AUTO_CANDIDATES the garment's validation touches prefer (trainer/relief.py)
AUTO_CANDIDATES = ("lift", "shade-lift")          # cheapest first: a tie keeps the cheaper graph
RULES = ("none", *GAIN_RULES, "shade", "shade-lift", "auto")
# What the rules do, for `eval --relief` and `export --relief`; each CLI adds what the rule means there.
HELP = ("calibrate the tactile output on the garment's training touches (trainer/relief.py): one gain (rms matches "
        "their relief's energy, ls is the least-squares gain, lift the ls gain floored at 1), or shade: the relief "
        "mixed with the visual's own shading (trainer/shading_fit.py; shade-lift keeps the relief's weight at 1 or "
        "above), or auto: lift or shade-lift, whichever the garment's validation touches prefer")
