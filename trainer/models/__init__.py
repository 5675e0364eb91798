"""Networks: the two-branch generator (ours), the ResNet-9 baseline generator, discriminators, positional encoding."""
