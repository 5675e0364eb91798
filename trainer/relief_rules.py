"""The names of the relief calibration rules (trainer/relief.py), apart so the CLIs list them without importing
torch."""

GAIN_RULES = ("rms", "ls", "lift")               # one gain: trainer/calibration.py
# shade: the visual's own shading mixed in (trainer/shading_fit.py); shade-lift: the same, the model's weight >= 1
# auto: whichever of AUTO_CANDIDATES the garment's validation touches prefer (trainer/relief.py)
AUTO_CANDIDATES = ("lift", "shade-lift")          # cheapest first: a tie keeps the cheaper graph
RULES = ("none", *GAIN_RULES, "shade", "shade-lift", "auto")
