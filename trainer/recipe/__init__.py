"""Training-recipe pieces shared by every method: learning-rate policy, DiffAugment, weight averaging, texture loss.

Each is switched by the run config and measured as an ablation (docs/training.md "recipe"), so a method file only
says where it applies them.
"""
