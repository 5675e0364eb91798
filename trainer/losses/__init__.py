"""Losses: non-saturating GAN, feature matching, perceptual (LPIPS-VGG or a documented substitute), CLIP-D."""
