"""Typed run configuration: frozen dataclasses read from a YAML preset (+ `--set section.key=value` overrides) by
the project's one loader (`kiosk.config.loader`), validated, printed and saved as `RUN/config.yaml` with every run.
"""
from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from kiosk.config import loader
from kiosk.contract.graph import GRID_MULTIPLE, is_grid
from trainer.errors import TrainerError
from trainer.models.generator import WAVE_HEADS
from trainer.recipe.diffaug import parse_policy
from trainer.recipe.schedule import POLICIES

PRESETS_DIR = Path(__file__).parent / "presets"
DEVICE_RE = re.compile(r"cpu|auto|cuda(:[0-9]+)?")

class ConfigError(TrainerError):
    """A preset or override that does not fit the typed config; the message names the key."""


@dataclass(frozen=True)
class DataConfig:
    crop: int = 1536              # training/eval crop side in padded-frame px (multiple of 256)
    fit_crop: bool = True         # grow the crop (multiples of 256) when the object does not fit in `crop`
    patches: int = 64             # paired tactile patches per step
    unpaired: int = 32            # unpaired fake patches per step (inside the object mask)
    candidates_per_touch: int = 4  # random centres drawn per touch before the Laplacian-weighted pick
    laplacian_floor: float = 0.1  # weight = var(Laplacian(sketch patch)) + floor * mean (flat areas still drawn)
    # Where unpaired fake patches land: "laplacian", weighted like the paired ones, or "uniform" over the object (the
    # paper), where the tactile D learns "plain cloth under the patch = fake" (docs/training.md, unpaired patches).
    unpaired_sampling: str = "laplacian"
    # Probability that a training crop is mirrored across its main diagonal (sketch, mask, photo, patches; the
    # tactile patches' gx and gy trade places): each touch then teaches relief at a second orientation. The diagonal
    # is the one mirror that keeps a photo lit from the upper left (the synthetic lamp, most studio set-ups) lit from
    # there; 0 = off (the paper). trainer/recipe/mirror.py.
    transpose: float = 0.0
    # Probability that a training crop is mirrored left to right (gx changes sign), after any diagonal mirror: it
    # keeps corduroy's wales and a knit's courses where the diagonal turns them, but moves the lamp to the upper
    # right, so it pairs with transpose_visual=false. 0 = off (the paper).
    flip: float = 0.0
    # Whether a mirrored crop (either mirror) also trains the visual branch and its discriminators (`ours` and its
    # ablations). The lamp is only near the diagonal and its falloff is not symmetric, so a mirrored photo is lit a
    # little wrong; false keeps every visual loss on crops as photographed and lets mirrored crops train the tactile
    # side only.
    transpose_visual: bool = True
    # Whether a mirrored crop is trained beside the crop as photographed, in the same step, instead of in its place
    # (`ours` and its ablations): a second generator pass on the mirrored twin trains the tactile side only, the
    # tactile terms are the mean over both passes, and every step trains the visual branch. A mirrored step costs a
    # second generator pass (about twice the wall time at flip=0.5 here). Needs data.transpose or data.flip above 0.
    mirror_extra: bool = False
    # Whether that twin also trains the tactile GAN (its patches are shown to the tactile D, and its GAN and
    # feature-matching terms reach G). False keeps the adversarial texture on crops as photographed and lets the twin
    # teach relief through the reconstruction terms only.
    twin_gan: bool = True


@dataclass(frozen=True)
class ModelConfig:
    base: int = 10
    pe_dim: int = 4
    outer_skip: bool = False
    tactile_mult: int = 1       # width multiplier of G's tactile head (up3..up0); the paper's is 1
    tactile_reads_visual: bool = False   # G's tactile head also reads the visual head's features (not the paper's)
    weave_waves: int = 0        # plane waves at the photo's weave frequencies mixed into G's heads (exploratory)
    weave_waves_heads: str = "both"   # which heads mix them: both, or the visual head only
    d_ndf: int = 8
    d_layers: int = 3
    d_scales: int = 3
    td_scales: int = 3
    d_norm: str = "batch"
    resnet_ngf: int = 64          # pix2pix-joint-d (the earlier pix2pix variant); the paper's baselines: `baseline`
    resnet_blocks: int = 9


@dataclass(frozen=True)
class BaselineConfig:
    """Widths of the paper's baselines (pix2pix, pix2pixHD, GauGAN), by default their authors' own: the paper ran
    each "with the default parameters of the original works". The cpu preset narrows them and says so."""
    ngf: int = 64                 # pix2pix ResNet generator, GauGAN (16 x ngf at the SPADE head)
    ndf: int = 64                 # every baseline discriminator's first layer
    resnet_blocks: int = 9        # pix2pix ResNet-9
    hd_ngf: int = 32              # pix2pixHD local enhancer (its global net has 2 x hd_ngf)
    hd_global_blocks: int = 9
    hd_local_blocks: int = 3
    spade_hidden: int = 128       # GauGAN SPADE shared-conv width


@dataclass(frozen=True)
class LossConfig:
    visual_l1: float = 100.0
    visual_perceptual: float = 1.0
    visual_gan: float = 1.0
    clip: float = 1.0
    feature_matching: float = 1.0
    tactile_gan: float = 5.0
    tactile_l1: float = 10.0
    tactile_perceptual: float = 10.0
    clip_start: float = 0.247     # fraction of the schedule before the CLIP-D starts (epoch 100 of 405)
    # What the tactile D is conditioned on (docs/training.md "tactile discriminator shortcuts"). The paper feeds fake
    # patches the *generated* visual crop; "real" gives real and fake patches the same ground-truth crop (dense in
    # training), so D cannot tell them apart by a visual difference the tactile branch cannot change; "none" shows D
    # no colour at all (one garment's fabric is fixed, so colour can only teach D a print-tactile correlation).
    tactile_d_visual: str = "generated"
    # Contact mask of unpaired fake patches: "borrowed" (a paired patch's sensor contact mask x the object mask) or
    # "object" (the object mask, as published: ~93 % contact where sensor patches have ~50 %, a giveaway to D).
    unpaired_contact: str = "borrowed"
    # Stabilisers of the tactile GAN, not in the paper (docs/training.md "tactile GAN stabilisation"). `tactile_r1`
    # is the R1 weight gamma (D loss += gamma / 2 * E|dD/dx|^2 on real patches; 0 = off, as published): without it
    # the tactile D wins outright within a few hundred steps and its x5 GAN term drags the tactile branch off the
    # data. `tactile_gan_ramp` is the fraction of the schedule over which the generator's tactile GAN weight rises
    # linearly from 0 to `tactile_gan` (0 = off).
    tactile_r1: float = 10.0   # 10 since the hard-profile measurements (docs/training.md, Fidelity II)
    tactile_gan_ramp: float = 0.0
    # DiffAugment on the discriminators' inputs (trainer/recipe/diffaug.py): comma-separated ops from color,
    # translation, cutout (the authors' `--use_diffaug` policy is all three; the default since it was measured at the
    # full schedule: docs/training.md "The recipe's pieces"); "" = off.
    diffaug: str = field(default="color,translation,cutout", metadata={"empty_ok": True})
    # Texture-statistics loss on tactile patches (trainer/recipe/texture.py): filter-bank mean + covariance match.
    tactile_texture: float = 0.0
    # Weave-scale visual loss (trainer/recipe/weave.py): L1 between the fine log-luminance bands of the generated and
    # the real photo, the bands the shading relief reads (`--relief shade`); 0 = off.
    visual_weave: float = 0.0
    # Photometric tactile loss (trainer/recipe/shading.py): the share of the real photo's fine log-luminance bands
    # that a per-crop linear mix of the relief's slopes leaves unexplained, over the whole object; 0 = off.
    tactile_shading: float = 0.0
    # Registration-tolerant touches (trainer/recipe/registration.py): every tactile term sees the generated relief at
    # the best integer shift within this many px of where each patch was recorded; 0 = at the recorded corner.
    tactile_shift: int = 0


@dataclass(frozen=True)
class OptimConfig:
    lr: float = 1e-3
    betas: tuple[float, float] = (0.0, 0.99)
    lr_tactile_d: float = 5e-4
    # "linear": every rate held, then decayed linearly to zero from `decay_from` (fraction of the schedule) to the
    # end, as the authors' runs (`lr_policy linear`, n_epochs = n_epochs_decay); "constant": never decayed.
    lr_policy: str = "linear"
    decay_from: float = 0.5


@dataclass(frozen=True)
class TrainConfig:
    steps: int = 81000            # 405 epochs x 200 iterations
    seed: int = 0
    threads: int = 2
    deterministic: bool = False
    log_every: int = 10
    val_every: int = 500
    sample_every: int = 2000
    ckpt_every: int = 2000
    progress: bool = True
    # Decay of the exponential moving average of G's weights used for validation, evaluation and export; 0 = off.
    ema: float = 0.0
    # Warm-up of that average: its decay at step s is min(ema, (1 + s) / (ema_ramp + s)), so until `ema` caps it the
    # average covers about the last 1 / (ema_ramp - 1) of the steps so far (10: the last ninth; 0.999 is reached at
    # step ~9 000, so a 2 000-step run never gets there). `ema_probe_ramp` > 0 keeps a second, passive average with
    # that ramp beside it (scored as `RUN@probe`): training is the same run, so the two ramps compare within it.
    ema_ramp: float = 10.0
    ema_probe_ramp: float = 0.0
    # Where the step runs: "cpu", "cuda", "cuda:N", or "auto" (the first GPU when torch sees one, else the CPU).
    # How a run is executed, not what it learns: a resume may change it and the recipe hash leaves it out.
    device: str = "cpu"
    # TF32 (10-bit mantissa) in a GPU's convolutions and matmuls: PyTorch's default for cuDNN convolutions, off here
    # so that a GPU computes what the CPU does in float32 (docs/training.md, "On a GPU").
    tf32: bool = False


@dataclass(frozen=True)
class PretrainedConfig:
    vgg16: str | None = None         # torchvision vgg16 state_dict (.pth)
    lpips_lin: str | None = None     # lpips v0.1 vgg linear layers (.pth)
    clip_encoder: str | None = None  # TorchScript image encoder: (N,3,224,224) in [-1,1] -> (N,D)
    inception: str | None = None     # torchvision inception_v3 state_dict (.pth), for SIFID


@dataclass(frozen=True)
class RunConfig:
    method: str = "ours"
    preset: str = "paper"
    data: DataConfig = field(default_factory=DataConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    baseline: BaselineConfig = field(default_factory=BaselineConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    pretrained: PretrainedConfig = field(default_factory=PretrainedConfig)
    garment: str = field(default="", metadata={"empty_ok": True})  # garment folder (absolute), filled by the CLI

    def to_dict(self) -> dict:
        return loader.to_mapping(self)

    def dump(self, path: Path) -> None:
        Path(path).write_text(yaml.safe_dump(self.to_dict(), sort_keys=False))


def load_config(preset: str | Path = "paper", *, overrides: list[str] | None = None,
                method: str | None = None) -> RunConfig:
    """A preset name (`paper`, `cpu`, `tiny`) or a YAML path, then `section.key=value` overrides."""
    path = Path(preset)
    if not path.suffix:
        path = PRESETS_DIR / f"{preset}.yaml"
    if not path.is_file():
        known = ", ".join(sorted(p.stem for p in PRESETS_DIR.glob("*.yaml")))
        raise ConfigError(f"no preset {preset!r} (known: {known}, or a path to a .yaml file)")
    doc = loader.load_yaml(path, error=ConfigError, what="preset")
    if "preset" not in doc:
        doc["preset"] = path.stem
    doc = loader.merge(doc, loader.parse_overrides(RunConfig, overrides or [], error=ConfigError))
    if method is not None:
        doc["method"] = method
    cfg = loader.build(RunConfig, doc, error=ConfigError, where=str(path))
    validate(cfg)
    return cfg


def config_from_dict(data: dict) -> RunConfig:
    """A run's saved config (`RUN/config.yaml`, a checkpoint's `config`) read back."""
    return loader.build(RunConfig, data, error=ConfigError)


def read_run_config(run_dir: str | Path) -> RunConfig:
    """The config a run saved as `RUN/config.yaml`; errors name the file."""
    path = Path(run_dir) / "config.yaml"
    return loader.build(RunConfig, loader.load_yaml(path, error=ConfigError, what="run config"), error=ConfigError,
                        where=str(path))


def validate(cfg: RunConfig) -> None:
    if not is_grid(cfg.data.crop):
        raise ConfigError(f"data.crop must be a multiple of {GRID_MULTIPLE} (the generator halves the grid eight "
                          f"times); got {cfg.data.crop}")
    if cfg.data.patches < 1:
        raise ConfigError("data.patches must be >= 1")
    if cfg.train.steps < 1:
        raise ConfigError("train.steps must be >= 1")
    for k in ("ngf", "ndf", "resnet_blocks", "hd_ngf", "hd_global_blocks", "hd_local_blocks", "spade_hidden"):
        if getattr(cfg.baseline, k) < 1:
            raise ConfigError(f"baseline.{k} must be >= 1; got {getattr(cfg.baseline, k)}")
    for k in ("log_every", "val_every", "sample_every", "ckpt_every", "threads"):
        if getattr(cfg.train, k) < 1:
            raise ConfigError(f"train.{k} must be >= 1")
    if not DEVICE_RE.fullmatch(cfg.train.device):
        raise ConfigError(f"train.device must be cpu, cuda, cuda:N or auto; got {cfg.train.device!r}")
    if cfg.model.tactile_mult < 1:
        raise ConfigError(f"model.tactile_mult must be >= 1; got {cfg.model.tactile_mult}")
    if not 0 <= cfg.model.weave_waves <= 32:
        raise ConfigError(f"model.weave_waves must be within 0..32; got {cfg.model.weave_waves}")
    if cfg.loss.tactile_r1 < 0:
        raise ConfigError(f"loss.tactile_r1 must be >= 0; got {cfg.loss.tactile_r1}")
    if not 0.0 <= cfg.loss.tactile_gan_ramp <= 1.0:
        raise ConfigError(f"loss.tactile_gan_ramp is a fraction of the schedule, 0..1; got {cfg.loss.tactile_gan_ramp}")
    if not 0.0 <= cfg.optim.decay_from <= 1.0:
        raise ConfigError(f"optim.decay_from is a fraction of the schedule, 0..1; got {cfg.optim.decay_from}")
    if not (cfg.train.ema == 0.0 or 0.0 < cfg.train.ema < 1.0):
        raise ConfigError(f"train.ema is a decay in (0, 1), or 0 for off; got {cfg.train.ema}")
    if not cfg.train.ema_ramp > 1.0:
        raise ConfigError(f"train.ema_ramp must be > 1 (the average covers 1 / (ramp - 1) of the steps); "
                          f"got {cfg.train.ema_ramp}")
    if not (cfg.train.ema_probe_ramp == 0.0 or cfg.train.ema_probe_ramp > 1.0):
        raise ConfigError(f"train.ema_probe_ramp is > 1, or 0 for no probe average; got {cfg.train.ema_probe_ramp}")
    if cfg.train.ema_probe_ramp and not cfg.train.ema:
        raise ConfigError("train.ema_probe_ramp needs train.ema (the probe shares its decay cap)")
    if not 0 <= cfg.loss.tactile_shift <= 8:
        raise ConfigError(f"loss.tactile_shift is a shift radius in px, 0..8; got {cfg.loss.tactile_shift}")
    if cfg.loss.visual_weave < 0:
        raise ConfigError(f"loss.visual_weave must be >= 0; got {cfg.loss.visual_weave}")
    if cfg.loss.tactile_shading < 0:
        raise ConfigError(f"loss.tactile_shading must be >= 0; got {cfg.loss.tactile_shading}")
    if cfg.loss.tactile_texture < 0:
        raise ConfigError(f"loss.tactile_texture must be >= 0; got {cfg.loss.tactile_texture}")
    for key in ("transpose", "flip"):
        if not 0.0 <= getattr(cfg.data, key) <= 1.0:
            raise ConfigError(f"data.{key} is a probability, in [0, 1]; got {getattr(cfg.data, key)}")
    if not cfg.data.twin_gan and not cfg.data.mirror_extra:
        raise ConfigError("data.twin_gan=false says what a mirrored twin trains; it needs data.mirror_extra=true")
    if cfg.data.mirror_extra and not (cfg.data.transpose or cfg.data.flip):
        raise ConfigError("data.mirror_extra adds a mirrored twin to mirrored steps; set data.transpose or data.flip "
                          "above 0 for there to be any")
    try:
        parse_policy(cfg.loss.diffaug)
    except ValueError as exc:
        raise ConfigError(f"loss.diffaug: {exc}") from exc
    choices = {("optim", "lr_policy"): POLICIES,
               ("data", "unpaired_sampling"): ("laplacian", "uniform"),
               ("loss", "tactile_d_visual"): ("generated", "real", "none"),
               ("loss", "unpaired_contact"): ("borrowed", "object"),
               ("model", "weave_waves_heads"): WAVE_HEADS}
    for (section, key), allowed in choices.items():
        value = getattr(getattr(cfg, section), key)
        if value not in allowed:
            raise ConfigError(f"{section}.{key} must be one of {', '.join(allowed)}; got {value!r}")
