"""The names of the relief calibration rules (trainer/relief.py), apart so the CLIs list them without importing
torch."""

GAIN_RULES = ("rms", "ls", "lift")               # one gain: trainer/calibration.py
RULES = ("none", *GAIN_RULES, "shade")           # shade: the visual's own shading mixed in, trainer/shading_fit.py
