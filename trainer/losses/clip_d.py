"""Vision-aided discriminator (Kumari et al. 2022): a frozen pretrained image encoder + a trainable MLP head.

The encoder comes from a local TorchScript file (`clip_encoder_path`) that maps (N, 3, S, S) images in [-1, 1]
to (N, D) features (export CLIP's image tower once with `torch.jit.trace`); nothing is downloaded. Without a path
the term is skipped with one log line. Unlike the published code, the head has its own optimizer, so it learns.
"""
from __future__ import annotations

import logging
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from trainer.losses.gan import d_loss, g_loss

log = logging.getLogger(__name__)


class ClipDiscriminator(nn.Module):
    """Shape: image (N, 3, H, W) in [-1, 1] -> logits (N, 1). The encoder is frozen; only `head` trains."""

    def __init__(self, *, encoder_path: str, input_size: int = 224, hidden: int = 256):
        super().__init__()
        path = Path(encoder_path)
        if not path.is_file():
            raise FileNotFoundError(f"CLIP encoder {path} not found")
        self.encoder = torch.jit.load(str(path), map_location="cpu").eval()
        for p in self.encoder.parameters():
            p.requires_grad_(False)
        self.input_size = input_size
        with torch.no_grad():
            dim = self.encoder(torch.zeros(1, 3, input_size, input_size)).reshape(1, -1).shape[1]
        self.head = nn.Sequential(nn.Linear(dim, hidden), nn.LeakyReLU(0.2), nn.Linear(hidden, 1))

    def train(self, mode: bool = True):
        super().train(mode)
        self.encoder.eval()
        return self

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        assert image.dim() == 4 and image.shape[1] == 3, f"expected (N, 3, H, W); got {tuple(image.shape)}"
        x = F.interpolate(image, size=(self.input_size, self.input_size), mode="bilinear", align_corners=False)
        f = self.encoder(x).reshape(image.shape[0], -1).float()
        return self.head(f)


class ClipD:
    """The head, its optimizer and its two loss terms, or nothing (with one log line) when no encoder is given."""

    def __init__(self, *, encoder_path: str | None, lr: float, betas: tuple[float, float], device="cpu"):
        self.net: ClipDiscriminator | None = None
        self.opt: torch.optim.Optimizer | None = None
        if not encoder_path:
            log.info("clip-d: no CLIP encoder configured (pretrained.clip_encoder); the vision-aided "
                     "discriminator is skipped")
            return
        if not Path(encoder_path).is_file():
            log.warning("clip-d: pretrained.clip_encoder %s is not a file; the vision-aided discriminator is skipped",
                        encoder_path)
            return
        self.net = ClipDiscriminator(encoder_path=encoder_path).to(device)
        self.opt = torch.optim.Adam(self.net.head.parameters(), lr=lr, betas=betas)

    @property
    def active(self) -> bool:
        return self.net is not None

    def d_step(self, real: torch.Tensor, fake: torch.Tensor, reduce=None) -> float:
        """One step of the head; `reduce(module)` averages its gradients across processes when distributed."""
        assert self.net is not None and self.opt is not None
        self.opt.zero_grad(set_to_none=True)
        loss = d_loss(self.net(real), self.net(fake.detach()))
        loss.backward()
        if reduce is not None:
            reduce(self.net.head)
        self.opt.step()
        return loss.item()

    def g_loss(self, fake: torch.Tensor) -> torch.Tensor:
        assert self.net is not None
        for p in self.net.head.parameters():
            p.requires_grad_(False)
        try:
            return g_loss(self.net(fake))
        finally:
            for p in self.net.head.parameters():
                p.requires_grad_(True)
