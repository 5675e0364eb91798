"""The kiosk daemon's configuration: typed dataclasses loaded from one YAML file (`vtkiosk serve --config`).

Every section is optional and has safe defaults (loopback only, signed bundles only, the emulated device). The
project's one loader (`kiosk.config.loader`) reads the file; unknown keys, wrong types and out-of-range values are
`ConfigError`s that name the file and key, so an operator sees
`kiosk.yaml: inference.threads must be an integer from 1 to 64` instead of a traceback at 3 a.m.
The `device` section is the bridge's own `firmware_bridge.config.BridgeConfig` (transport plugin chosen by `type`).
See `configs/kiosk.example.yaml` for every key with a comment.
"""
from __future__ import annotations

import dataclasses
import ipaddress
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from firmware_bridge.config import BridgeConfig
from kiosk.bundle.manifest import PRECISIONS
from kiosk.config import loader
from kiosk.contract.errors import KioskError
from kiosk.contract.graph import GRID_MULTIPLE
from kiosk.fleet.layout import CHANNELS, KIOSK_ID_RE
from kiosk.inference.scene import QUICK_TACTILE
from kiosk.inference.sessions import EXECUTION_MODES, OPENVINO_HINTS, SessionSettings
from kiosk.contract.panels import DEFAULT_PANEL, KNOWN_PANELS

PROVIDERS = {"cpu": "CPUExecutionProvider", "cuda": "CUDAExecutionProvider", "tensorrt": "TensorrtExecutionProvider",
             "openvino": "OpenVINOExecutionProvider"}
_LABEL = r"[A-Za-z0-9](?:[A-Za-z0-9-]{0,61}[A-Za-z0-9])?"
_NAME_RE = re.compile(rf"\A(?=.{{1,253}}\Z){_LABEL}(?:\.{_LABEL})*\.?\Z")


class ConfigError(KioskError):
    """The kiosk configuration is invalid; the message names the file and key."""


@dataclass(frozen=True)
class ServerConfig:
    """HTTP server of the page and its API. Loopback only unless `allow_non_loopback` (the page has no login)."""

    host: str = "127.0.0.1"
    port: int = 8765
    allow_non_loopback: bool = False
    request_timeout_s: float = 10.0
    header_timeout_s: float = 10.0     # a request (line, headers, body) must arrive within this
    max_connections: int = 64          # connections served at once; the next gets a 503
    names: tuple[str, ...] = ()        # Host names the page may be reached by, beside the listen address

    def __post_init__(self) -> None:
        _check(0 <= self.port <= 65535, "server.port must be from 0 (any free port) to 65535")
        _check(self.request_timeout_s > 0, "server.request_timeout_s must be > 0")
        _check(0 < self.header_timeout_s <= 300, "server.header_timeout_s must be > 0 and at most 300")
        _check(1 <= self.max_connections <= 4096, "server.max_connections must be from 1 to 4096")
        for name in self.names:
            _check(bool(_NAME_RE.match(name)), f"server.names: {name[:80]!r} is not a host name")
        if not self.allow_non_loopback and not is_loopback(self.host):
            raise ConfigError(f"server.host {self.host!r} is not a loopback address; the kiosk page has no login, so "
                              "it is served on 127.0.0.1 only (set server.allow_non_loopback: true to override)")


@dataclass(frozen=True)
class StoreConfig:
    """Where installed bundles live (the `kiosk.bundle.store.BundleStore` layout) and which keys may sign them."""

    root: Path | None = None
    trusted_keys: Path | None = None
    allow_unsigned: bool = False


ENGINE_TYPES = ("onnxruntime", "openvino", "auto")


@dataclass(frozen=True)
class OrtSessionConfig:
    """ONNX Runtime session settings (`kiosk.inference.sessions`; defaults measured by `vtkiosk bench threads`,
    docs/performance.md). mem_arena: keep freed activation memory in ONNX Runtime's own arena; mem_pattern: plan
    activation memory once per input shape; execution_mode: sequential or parallel execution of independent nodes."""

    mem_arena: bool = True
    mem_pattern: bool = True
    execution_mode: str = "sequential"

    def __post_init__(self) -> None:
        _check(self.execution_mode in EXECUTION_MODES,
               f"inference.engine.onnxruntime.execution_mode must be one of {', '.join(EXECUTION_MODES)}")


@dataclass(frozen=True)
class OpenVinoSessionConfig:
    """OpenVINO compile settings: streams (requests the CPU plugin runs at once, sharing the threads) and the
    performance hint (latency: one request on every thread; throughput: threads split between streams)."""

    streams: int = 1
    hint: str = "latency"

    def __post_init__(self) -> None:
        _check(1 <= self.streams <= 16, "inference.engine.openvino.streams must be an integer from 1 to 16")
        _check(self.hint in OPENVINO_HINTS,
               f"inference.engine.openvino.hint must be one of {', '.join(OPENVINO_HINTS)}")


@dataclass(frozen=True)
class EngineConfig:
    """Which engine runs the bundle's ONNX graphs (`kiosk.inference.backends`). auto: time the installed engines on
    each bundle at activation and keep the fastest inside the bundle's stated error (auto_runs timed runs each).
    `onnxruntime` and `openvino`: each engine's session settings (used whenever that engine runs, auto included)."""

    type: str = "onnxruntime"
    auto_runs: int = 3
    onnxruntime: OrtSessionConfig = field(default_factory=OrtSessionConfig)
    openvino: OpenVinoSessionConfig = field(default_factory=OpenVinoSessionConfig)

    def __post_init__(self) -> None:
        _check(self.type in ENGINE_TYPES, f"inference.engine.type must be one of {', '.join(ENGINE_TYPES)}")
        _check(1 <= self.auto_runs <= 50, "inference.engine.auto_runs must be from 1 to 50")
        if self.type == "openvino":
            from kiosk.inference.backends import available

            _check("openvino" in available(),
                   "inference.engine.type is openvino, which is not installed (pip install 'vtkiosk[openvino]')")


@dataclass(frozen=True)
class InferenceConfig:
    """ONNX Runtime settings and the scene planner's limits.

    max_resolution: the longest network-grid side the planner may use (a multiple of 256; also capped by the
    bundle's declared sizes). preview_max_resolution: the same while a stroke is being drawn.
    latency_budget_ms: a new bundle must answer its probe within this, and the inference loop's p95 must stay
    under it for the kiosk to count as healthy. threads: the main lane's threads (stroke ends and refinements).
    preview_threads: previews while drawing run in a lane of their own with this many threads, beside a running
    refinement instead of queued behind it; 0 runs them in the one main loop, in turn with everything else.
    refine: answer a stroke end first at the preview resolution (visual and friction), then at full resolution (the
    page asks for the refinement at once). quick_tactile: at-scale (default) leaves the friction of a quick answer
    to the refinement when the quick grid would make the texture felt more than 10 % coarser than the fabric;
    always sends it anyway (the earlier behaviour). precisions: the graph precisions this kiosk runs (a bundle
    carries one precision per graph; one with another, e.g. fp16 on a CPU-only kiosk, is refused at load with a
    clear reason).
    """

    threads: int = 2
    preview_threads: int = 1
    provider: str = "cpu"
    precisions: tuple[str, ...] = ("int8", "fp32", "fp16")
    latency_budget_ms: float = 100.0
    max_resolution: int = 512
    preview_max_resolution: int = 256
    margin_px: int = 16
    cache_mb: int = 64
    refine: bool = True
    quick_tactile: str = "at-scale"
    engine: EngineConfig = field(default_factory=EngineConfig)

    def __post_init__(self) -> None:
        _check(1 <= self.threads <= 64, "inference.threads must be an integer from 1 to 64")
        _check(0 <= self.preview_threads <= 64, "inference.preview_threads must be an integer from 0 (previews share "
               "the main loop) to 64")
        _check(self.provider in PROVIDERS, f"inference.provider must be one of {', '.join(PROVIDERS)}")
        _check(len(self.precisions) > 0 and all(p in PRECISIONS for p in self.precisions),
               f"inference.precisions must be a non-empty list of {', '.join(PRECISIONS)}")
        _check(self.latency_budget_ms > 0, "inference.latency_budget_ms must be > 0")
        for name in ("max_resolution", "preview_max_resolution"):
            v = getattr(self, name)
            _check(v >= GRID_MULTIPLE and v % GRID_MULTIPLE == 0 and v <= 4096,
                   f"inference.{name} must be a multiple of {GRID_MULTIPLE} from {GRID_MULTIPLE} to 4096")
        _check(self.preview_max_resolution <= self.max_resolution,
               "inference.preview_max_resolution must not exceed inference.max_resolution")
        _check(self.quick_tactile in QUICK_TACTILE,
               f"inference.quick_tactile must be one of {', '.join(QUICK_TACTILE)}")
        _check(0 <= self.margin_px <= 512, "inference.margin_px must be from 0 to 512")
        _check(0 <= self.cache_mb <= 4096, "inference.cache_mb must be from 0 to 4096 (MiB of cached outputs)")

    def session_settings(self) -> SessionSettings:
        """Both engines' session settings (the lane decides the threads)."""
        ort_cfg, ov = self.engine.onnxruntime, self.engine.openvino
        return SessionSettings(threads=self.threads, mem_arena=ort_cfg.mem_arena, mem_pattern=ort_cfg.mem_pattern,
                               execution_mode=ort_cfg.execution_mode, streams=ov.streams, hint=ov.hint)

    @property
    def providers(self) -> list[str]:
        return [PROVIDERS[self.provider]] + ([] if self.provider == "cpu" else ["CPUExecutionProvider"])


@dataclass(frozen=True)
class PanelConfig:
    """The haptic screen's physical size, so texture is rendered at true scale (`kiosk.contract.panels`).

    model: a known panel (its pixels and size); width_mm/height_mm and width_px/height_px, when given, override it
    (state all four for a panel not in the table). Pixels must be square within 3 %.
    """

    model: str | None = DEFAULT_PANEL
    width_mm: float | None = None
    height_mm: float | None = None
    width_px: int | None = None
    height_px: int | None = None

    def __post_init__(self) -> None:
        if self.model is not None:
            _check(self.model in KNOWN_PANELS, f"panel.model {self.model!r} is not a known panel (known: "
                   f"{', '.join(sorted(KNOWN_PANELS))}); state panel.width_mm, height_mm, width_px, height_px instead")
        w_mm, h_mm, w_px, h_px = self.dims
        for name, v in (("width_mm", w_mm), ("height_mm", h_mm), ("width_px", w_px), ("height_px", h_px)):
            _check(v is not None, f"panel.{name} is needed (no panel.model gives it)")
        _check(10.0 <= w_mm <= 5000.0 and 10.0 <= h_mm <= 5000.0, "panel.width_mm and height_mm must be from 10 to 5000")
        _check(16 <= w_px <= 16384 and 16 <= h_px <= 16384, "panel.width_px and height_px must be from 16 to 16384")
        px, py = w_mm / w_px, h_mm / h_px
        _check(abs(px - py) <= 0.03 * max(px, py), f"panel pixels are not square: {px:.4f} mm wide, {py:.4f} mm high "
               "(check panel.width_mm, height_mm, width_px, height_px)")

    @property
    def dims(self) -> tuple:
        k = KNOWN_PANELS.get(self.model) if self.model else None
        return (self.width_mm if self.width_mm is not None else (k.width_mm if k else None),
                self.height_mm if self.height_mm is not None else (k.height_mm if k else None),
                self.width_px if self.width_px is not None else (k.width_px if k else None),
                self.height_px if self.height_px is not None else (k.height_px if k else None))

    @property
    def pitch_mm(self) -> float:
        """mm per screen pixel (the mean of both axes)."""
        w_mm, h_mm, w_px, h_px = self.dims
        return 0.5 * (w_mm / w_px + h_mm / h_px)

    def describe(self) -> dict:
        w_mm, h_mm, w_px, h_px = self.dims
        k = KNOWN_PANELS.get(self.model) if self.model else None
        return {"model": self.model, "size_mm": [w_mm, h_mm], "size_px": [w_px, h_px],
                "pitch_mm": round(self.pitch_mm, 5),
                "source": "kiosk config" if (self.width_mm or self.height_mm) or k is None else k.source}


@dataclass(frozen=True)
class HealthConfig:
    """Health checks behind the watchdog and /healthz. stale_after_s: the inference loop must beat this often
    (it beats while idle too); device_max_heartbeat_age_s: the haptic link's last heartbeat must be this fresh."""

    stale_after_s: float = 5.0
    device_max_heartbeat_age_s: float = 2.0
    require_device: bool = True
    interval_s: float = 1.0

    def __post_init__(self) -> None:
        for name in ("stale_after_s", "device_max_heartbeat_age_s", "interval_s"):
            _check(getattr(self, name) > 0, f"health.{name} must be > 0 seconds")


@dataclass(frozen=True)
class ControlConfig:
    """The operator's control socket (reload, status); None disables it."""

    socket: Path | None = None
    group: str | None = None


@dataclass(frozen=True)
class DebugConfig:
    """fault_injection: allow the control ops `debug.hang`, `debug.unplug` ... that tests use to break the kiosk on
    purpose. Off in production."""

    fault_injection: bool = False


MAX_TEXT_CHARS = 200  # a line a shopper reads at arm's length; longer text breaks the page's layout


@dataclass(frozen=True)
class PageTexts:
    """Every sentence the shopper's page shows, so a store can reword or translate it without touching code.
    The page picks the hint that matches its state (Draw or Feel mode, with or without a garment)."""

    title: str = "Draw it. See it. Feel it."
    invite: str = "Touch the screen to start"
    draw: str = "Draw"
    feel: str = "Feel"
    undo: str = "Undo"
    clear: str = "Clear"
    outline: str = "Start from its outline"
    catalogue: str = "Fabrics"
    feeling: str = "You are feeling"
    hint_draw_empty: str = "Draw the outline of a garment with one finger. Close the outline to see it made."
    hint_draw: str = "Keep drawing to change your garment, or tap Feel to touch its fabric."
    hint_feel: str = "Slide your finger over the garment to feel the fabric. Tap Draw to change it."
    hint_feel_empty: str = "Nothing to feel yet: tap Draw and draw a garment, or pick a fabric."
    hint_pen: str = "Draw with the pen. Slide a finger over the garment to feel the fabric."
    ready: str = "Your garment is ready: slide a finger over it to feel the fabric."

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            _check(len(v) <= MAX_TEXT_CHARS and "\n" not in v,
                   f"page.texts.{f.name} must be one line of at most {MAX_TEXT_CHARS} characters")


@dataclass(frozen=True)
class PageConfig:
    """The shopper's page: the store loop's timings and its texts.

    idle_timeout_s: no touch for this long clears the drawing and the friction frame and shows the attract screen.
    attract_garment_s: how long the attract screen spends drawing and filling in each catalogue garment.
    auto_feel: switch to Feel mode when a drawing first closes into a garment. pen_draws: once a pen has touched
    the screen, the pen always draws and a finger always feels (the toggle stays as the way back).
    tap_max_px: a touch that never moves farther than this (CSS pixels) is a tap and leaves no ink.
    """

    idle_timeout_s: float = 90.0
    attract_garment_s: float = 6.0
    auto_feel: bool = True
    pen_draws: bool = True
    tap_max_px: float = 6.0
    texts: PageTexts = field(default_factory=PageTexts)

    def __post_init__(self) -> None:
        _check(0.5 <= self.idle_timeout_s <= 3600.0, "page.idle_timeout_s must be from 0.5 to 3600 seconds")
        _check(2.0 <= self.attract_garment_s <= 120.0, "page.attract_garment_s must be from 2 to 120 seconds")
        _check(0.0 <= self.tap_max_px <= 100.0, "page.tap_max_px must be from 0 to 100 (CSS pixels)")

    def to_json(self) -> dict:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class FleetConfig:
    """Fleet updates (`vtkiosk fleet sync`, docs/fleet.md); no url: this kiosk takes no part in a fleet.

    url: the repository's base URL (metadata/ and targets/ under it). root: the trust anchor, the root metadata from
    the key ceremony, provisioned with the kiosk (never fetched from the server). kiosk_id: this kiosk's name, whose
    hash decides its staged-rollout bucket. channel: canary or stable. state_dir: TUF metadata cache, downloads and
    the last sync's result. attempts, backoff_s: tries per sync while the repository does not answer, waiting
    backoff_s, then twice that ... (at most max_backoff_s, jittered). stale_after_s: /healthz calls the metadata
    stale past this age (the kiosk keeps serving).
    """

    url: str | None = None
    root: Path | None = None
    kiosk_id: str | None = None
    channel: str = "stable"
    state_dir: Path = Path("/var/lib/vtkiosk/fleet")
    attempts: int = 3
    backoff_s: float = 5.0
    max_backoff_s: float = 60.0
    timeout_s: float = 30.0
    stale_after_s: float = 86400.0

    def __post_init__(self) -> None:
        _check(self.channel in CHANNELS, f"fleet.channel must be one of {', '.join(CHANNELS)}")
        _check(1 <= self.attempts <= 10, "fleet.attempts must be from 1 to 10")
        _check(0 <= self.backoff_s <= 3600 and 0 <= self.max_backoff_s <= 3600,
               "fleet.backoff_s and fleet.max_backoff_s must be from 0 to 3600 seconds")
        _check(0 < self.timeout_s <= 600, "fleet.timeout_s must be > 0 and at most 600 seconds")
        _check(self.stale_after_s > 0, "fleet.stale_after_s must be > 0 seconds")
        if self.url is not None:
            _check(self.url.startswith(("http://", "https://")), "fleet.url must be an http:// or https:// URL")
            _check(self.root is not None, "fleet.root (the trust anchor root.json) is required with fleet.url")
            _check(self.kiosk_id is not None and bool(KIOSK_ID_RE.match(self.kiosk_id)),
                   "fleet.kiosk_id is required with fleet.url (1 to 128 letters, digits, '.', '_', ':', '-')")

    @property
    def enabled(self) -> bool:
        return self.url is not None


@dataclass(frozen=True)
class KioskConfig:
    server: ServerConfig = field(default_factory=ServerConfig)
    store: StoreConfig = field(default_factory=StoreConfig)
    bundles: tuple[Path, ...] = ()
    device: BridgeConfig = field(default_factory=BridgeConfig)
    inference: InferenceConfig = field(default_factory=InferenceConfig)
    panel: PanelConfig = field(default_factory=PanelConfig)
    health: HealthConfig = field(default_factory=HealthConfig)
    control: ControlConfig = field(default_factory=ControlConfig)
    debug: DebugConfig = field(default_factory=DebugConfig)
    fleet: FleetConfig = field(default_factory=FleetConfig)
    page: PageConfig = field(default_factory=PageConfig)
    state_dir: Path | None = None
    log_level: str = "INFO"

    def __post_init__(self) -> None:
        _check(self.log_level in ("DEBUG", "INFO", "WARNING", "ERROR"),
               "log_level must be DEBUG, INFO, WARNING or ERROR")
        if not self.bundles and self.store.root is None:
            raise ConfigError("no bundles to serve: set store.root (installed bundles) or bundles: [FILE, ...]")

    def replace(self, **changes: Any) -> "KioskConfig":
        return dataclasses.replace(self, **changes)


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _check(cond: bool, msg: str) -> None:
    if not cond:
        raise ConfigError(msg)


def config_from_mapping(data: Any, *, base_dir: Path | None = None) -> KioskConfig:
    """Validate a parsed config document. Relative paths are resolved against `base_dir` (the file's folder)."""
    return loader.build(KioskConfig, data, error=ConfigError, base_dir=base_dir)


def load_config(path: Path | None, overrides: dict | None = None) -> KioskConfig:
    """Read and validate a kiosk YAML file (or none: defaults), with command-line `overrides` merged in by
    section; every failure is a ConfigError naming the file."""
    return loader.load(KioskConfig, path, error=ConfigError, overrides=overrides, what="kiosk config")
