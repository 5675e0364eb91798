"""Perceptual loss: LPIPS with a VGG16 backbone when its weights are on disk, else a documented substitute.

Pretrained weights cannot be downloaded here, so they come from paths in the config:
- `vgg16_path`: a torchvision `vgg16` state_dict (or LPIPS' copy); only the `features.*` keys are used, and our
  `VGG16Features` uses the same key names, so the file loads as is.
- `lpips_lin_path`: the LPIPS linear-layer weights (`lin0.model.1.weight` ... `lin4.model.1.weight`, lpips v0.1).
With only the VGG weights, the five layers are averaged with equal weights ("vgg-uniform"). With neither, the loss
is the substitute "ssim-gradient": (1 - SSIM) + L1 of image gradients, at three scales - structure-sensitive like
LPIPS, without a learned backbone. `kind` says which one is in use and is recorded in the run. Never a random VGG.
"""
from __future__ import annotations

import logging
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

log = logging.getLogger(__name__)

VGG16_CFG = [64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512, "M"]
LPIPS_TAPS = (3, 8, 15, 22, 29)          # relu1_2, relu2_2, relu3_3, relu4_3, relu5_3 in `features`
LPIPS_CHANNELS = (64, 128, 256, 512, 512)


class VGG16Features(nn.Module):
    """torchvision's `vgg16().features`, rebuilt so its state_dict keys are `features.<i>.weight|bias`."""

    def __init__(self):
        super().__init__()
        layers: list[nn.Module] = []
        cin = 3
        for v in VGG16_CFG:
            if v == "M":
                layers.append(nn.MaxPool2d(2, 2))
            else:
                layers += [nn.Conv2d(cin, v, 3, padding=1), nn.ReLU(inplace=False)]
                cin = v
        self.features = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        taps = []
        for i, layer in enumerate(self.features):
            x = layer(x)
            if i in LPIPS_TAPS:
                taps.append(x)
            if i >= LPIPS_TAPS[-1]:
                break
        return taps


def _gauss(size: int = 11, sigma: float = 1.5, *, device=None, dtype=torch.float32) -> torch.Tensor:
    x = torch.arange(size, device=device, dtype=dtype) - (size - 1) / 2
    g = torch.exp(-(x ** 2) / (2 * sigma ** 2))
    g = g / g.sum()
    return (g[:, None] * g[None, :])[None, None]


def ssim(x: torch.Tensor, y: torch.Tensor, *, data_range: float = 2.0, window: int = 11,
         reduce: bool = True) -> torch.Tensor:
    """SSIM (Wang et al. 2004; Gaussian window 11, sigma 1.5, valid region), per channel then averaged.

    Shape: x, y (N, C, H, W) with H, W >= window (smaller inputs use a window of their size).
    """
    assert x.shape == y.shape and x.dim() == 4, f"x, y must be equal (N, C, H, W); got {x.shape}, {y.shape}"
    n, c, h, w = x.shape
    window = min(window, h, w)
    k = _gauss(window, 1.5 * window / 11, device=x.device, dtype=x.dtype).expand(c, 1, -1, -1)
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    mu_x, mu_y = F.conv2d(x, k, groups=c), F.conv2d(y, k, groups=c)
    sxx = F.conv2d(x * x, k, groups=c) - mu_x ** 2
    syy = F.conv2d(y * y, k, groups=c) - mu_y ** 2
    sxy = F.conv2d(x * y, k, groups=c) - mu_x * mu_y
    s = ((2 * mu_x * mu_y + c1) * (2 * sxy + c2)) / ((mu_x ** 2 + mu_y ** 2 + c1) * (sxx + syy + c2))
    return s.mean() if reduce else s.mean(dim=(1, 2, 3))


def _grad(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    return x[..., :, 1:] - x[..., :, :-1], x[..., 1:, :] - x[..., :-1, :]


def structure_loss(x: torch.Tensor, y: torch.Tensor, *, scales: int = 3) -> torch.Tensor:
    """The substitute: mean over scales of (1 - SSIM) + L1 between image gradients."""
    total = x.new_zeros(())
    used = 0
    for k in range(scales):
        if k:
            if min(x.shape[-2:]) < 8:
                break
            x, y = F.avg_pool2d(x, 2), F.avg_pool2d(y, 2)
        gx1, gy1 = _grad(x)
        gx2, gy2 = _grad(y)
        total = total + (1 - ssim(x, y)) + F.l1_loss(gx1, gx2) + F.l1_loss(gy1, gy2)
        used += 1
    return total / used


def _load_state(path: Path, what: str) -> dict:
    obj = torch.load(path, map_location="cpu", weights_only=True)
    if isinstance(obj, dict) and "state_dict" in obj and isinstance(obj["state_dict"], dict):
        obj = obj["state_dict"]
    if not isinstance(obj, dict):
        raise ValueError(f"{path}: expected a state_dict for {what}")
    return {k.removeprefix("module.").removeprefix("net."): v for k, v in obj.items()}


class Perceptual(nn.Module):
    """LPIPS-VGG distance (or the substitute) between two (N, 3, H, W) images in [-1, 1]; returns a scalar mean.

    Frozen: its parameters never train. `kind` is "lpips-vgg", "vgg-uniform" or "ssim-gradient".
    """

    def __init__(self, *, vgg16_path: str | None = None, lpips_lin_path: str | None = None, quiet: bool = False):
        super().__init__()
        self.kind = "ssim-gradient"
        self.vgg: VGG16Features | None = None
        self.register_buffer("shift", torch.tensor([-0.030, -0.088, -0.188]).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor([0.458, 0.448, 0.450]).view(1, 3, 1, 1))
        if vgg16_path and Path(vgg16_path).is_file():
            vgg = VGG16Features()
            state = {k: v for k, v in _load_state(Path(vgg16_path), "VGG16").items() if k.startswith("features.")}
            missing, _ = vgg.load_state_dict(state, strict=False)
            if missing:
                raise ValueError(f"{vgg16_path}: not a VGG16 features state_dict (missing {missing[:3]}...)")
            self.vgg = vgg.eval().requires_grad_(False)
            self.lins = nn.ParameterList([nn.Parameter(torch.full((1, c, 1, 1), 1.0 / c), requires_grad=False)
                                          for c in LPIPS_CHANNELS])
            self.kind = "vgg-uniform"
            if lpips_lin_path and Path(lpips_lin_path).is_file():
                lin = _load_state(Path(lpips_lin_path), "LPIPS linear layers")
                for i in range(5):
                    w = lin.get(f"lin{i}.model.1.weight")
                    if w is None or tuple(w.shape) != (1, LPIPS_CHANNELS[i], 1, 1):
                        raise ValueError(f"{lpips_lin_path}: missing or misshaped lin{i}.model.1.weight")
                    self.lins[i].data.copy_(w)
                self.kind = "lpips-vgg"
            elif not quiet:
                log.warning("perceptual: no LPIPS linear weights (lpips_lin_path); VGG layers weighted uniformly")
        elif not quiet:
            # configured but missing is an operator's mistake; not configured is the documented fallback
            (log.warning if vgg16_path else log.info)(
                "perceptual: %s; using the substitute (1-SSIM)+gradient L1 at 3 scales",
                f"pretrained.vgg16 {vgg16_path} is not a file" if vgg16_path else
                "no VGG16 weights configured (pretrained.vgg16)")

    def train(self, mode: bool = True):
        super().train(mode)
        if self.vgg is not None:
            self.vgg.eval()
        return self

    def forward(self, x: torch.Tensor, y: torch.Tensor, *, reduce: bool = True) -> torch.Tensor:
        assert x.shape == y.shape and x.dim() == 4 and x.shape[1] == 3, \
            f"expected two (N, 3, H, W) images; got {tuple(x.shape)}, {tuple(y.shape)}"
        if self.vgg is None:
            return structure_loss(x, y)
        fx = self.vgg((x - self.shift) / self.scale)
        fy = self.vgg((y - self.shift) / self.scale)
        d = x.new_zeros(x.shape[0])
        for a, b, w in zip(fx, fy, self.lins):
            a = a / (a.norm(dim=1, keepdim=True) + 1e-10)
            b = b / (b.norm(dim=1, keepdim=True) + 1e-10)
            d = d + ((a - b) ** 2 * w).sum(1).mean(dim=(1, 2))
        return d.mean() if reduce else d


def per_channel(loss: Perceptual, x: torch.Tensor, y: torch.Tensor, *, size: int | None = None) -> torch.Tensor:
    """Perceptual distance of each channel as a grey 3-channel image (tactile gx, gy); nearest resize to `size`."""
    total = x.new_zeros(())
    for c in range(x.shape[1]):
        a, b = x[:, c:c + 1], y[:, c:c + 1]
        if size is not None:
            a, b = F.interpolate(a, size=size, mode="nearest"), F.interpolate(b, size=size, mode="nearest")
        total = total + loss(a.expand(-1, 3, -1, -1), b.expand(-1, 3, -1, -1))
    return total / x.shape[1]
