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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from firmware_bridge.config import BridgeConfig
from kiosk.bundle.manifest import PRECISIONS
from kiosk.config import loader
from kiosk.contract.errors import KioskError
from kiosk.contract.graph import GRID_MULTIPLE
PROVIDERS = {"cpu": "CPUExecutionProvider", "cuda": "CUDAExecutionProvider", "tensorrt": "TensorrtExecutionProvider",
             "openvino": "OpenVINOExecutionProvider"}


class ConfigError(KioskError):
    """The kiosk configuration is invalid; the message names the file and key."""


@dataclass(frozen=True)
class ServerConfig:
    """HTTP server of the page and its API. Loopback only unless `allow_non_loopback` (the page has no login)."""

    host: str = "127.0.0.1"
    port: int = 8765
    allow_non_loopback: bool = False
    request_timeout_s: float = 10.0

    def __post_init__(self) -> None:
        _check(0 <= self.port <= 65535, "server.port must be from 0 (any free port) to 65535")
        _check(self.request_timeout_s > 0, "server.request_timeout_s must be > 0")
        if not self.allow_non_loopback and not is_loopback(self.host):
            raise ConfigError(f"server.host {self.host!r} is not a loopback address; the kiosk page has no login, so "
                              "it is served on 127.0.0.1 only (set server.allow_non_loopback: true to override)")


@dataclass(frozen=True)
class StoreConfig:
    """Where installed bundles live (the `kiosk.bundle.store.BundleStore` layout) and which keys may sign them."""

    root: Path | None = None
    trusted_keys: Path | None = None
    allow_unsigned: bool = False


@dataclass(frozen=True)
class InferenceConfig:
    """ONNX Runtime settings and the scene planner's limits.

    max_resolution: the longest network-grid side the planner may use (a multiple of 256; also capped by the
    bundle's declared sizes). preview_max_resolution: the same while a stroke is being drawn.
    latency_budget_ms: a new bundle must answer its probe within this, and the inference loop's p95 must stay
    under it for the kiosk to count as healthy. refine: answer a stroke end first at the preview resolution (visual
    and friction), then at full resolution (the page asks for the refinement at once). precisions: the graph
    precisions this kiosk runs (a bundle carries one precision per graph; one with another, e.g. fp16 on a CPU-only
    kiosk, is refused at load with a clear reason).
    """

    threads: int = 2
    provider: str = "cpu"
    precisions: tuple[str, ...] = ("int8", "fp32", "fp16")
    latency_budget_ms: float = 100.0
    max_resolution: int = 512
    preview_max_resolution: int = 256
    margin_px: int = 16
    cache_mb: int = 64
    refine: bool = True

    def __post_init__(self) -> None:
        _check(1 <= self.threads <= 64, "inference.threads must be an integer from 1 to 64")
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
        _check(0 <= self.margin_px <= 512, "inference.margin_px must be from 0 to 512")
        _check(0 <= self.cache_mb <= 4096, "inference.cache_mb must be from 0 to 4096 (MiB of cached outputs)")

    @property
    def providers(self) -> list[str]:
        return [PROVIDERS[self.provider]] + ([] if self.provider == "cpu" else ["CPUExecutionProvider"])


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


@dataclass(frozen=True)
class KioskConfig:
    server: ServerConfig = field(default_factory=ServerConfig)
    store: StoreConfig = field(default_factory=StoreConfig)
    bundles: tuple[Path, ...] = ()
    device: BridgeConfig = field(default_factory=BridgeConfig)
    inference: InferenceConfig = field(default_factory=InferenceConfig)
    health: HealthConfig = field(default_factory=HealthConfig)
    control: ControlConfig = field(default_factory=ControlConfig)
    debug: DebugConfig = field(default_factory=DebugConfig)
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
