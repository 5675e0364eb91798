"""`vtkiosk study run`: the kiosk daemon in study mode, with the study service mounted on it.

The daemon (kiosk.service.daemon.KioskDaemon) does what it always does: plans scenes, runs ONNX Runtime, turns tactile
output into friction maps and puts them on the haptic device. Study mode changes two things:
- what it serves: every (condition, garment) bundle of the study, each under the name `<condition>:<garment>`
  (the conditions share garment ids, so the garment id alone cannot name them). `study_sources` supplies these as
  the daemon's bundle candidates, so they are verified, probed and reported by the daemon's own reload path;
- what is shown: the study service builds each trial's two-panel scene (reference visual, model tactile, the same
  half) and calls `KioskDaemon.show`; the planner runs the tactile graphs only. The study page is at /study, its
  API under /api/study/, the operator's ops (`study.start|status|stop`) on the daemon's control socket.
"""
from __future__ import annotations

import faulthandler
import sys
from pathlib import Path
from typing import Any

from kiosk.config import loader
from kiosk.service.config import KioskConfig, config_from_mapping
from kiosk.service.daemon import KioskDaemon
from kiosk.inference.engine import LoadedBundle
from kiosk.ops.health import storage_check
from kiosk.ops.logsetup import configure_logging, say_line
from kiosk.ops.signals import on_signals
from kiosk.inference.scene import Panel, Scene, SketchInput
from kiosk.study.bundles import StudyBundle, StudyBundles, open_study_bundles
from kiosk.study.config import StudyConfig, StudyConfigError, load_study_config
from kiosk.study.log import StudyLog
from kiosk.study.service import Rendered, StudyError, StudyService

COMMIT_TIMEOUT_S = 10.0
SHUTDOWN_STACKS_AFTER_S = 20.0   # a stop slower than this dumps all thread stacks to stderr


class _ConditionBundle(LoadedBundle):
    """A study bundle served under `<condition>:<garment>` (what the daemon keys bundles and panels by)."""

    def __init__(self, sb: StudyBundle, **kwargs: Any) -> None:
        self.study_name = bundle_name(sb)
        super().__init__(sb.bundle, **kwargs)

    @property
    def garment_id(self) -> str:
        return self.study_name

    def graphs(self) -> tuple[str, ...]:
        """Study trials show the reference visual, so only the tactile graph is ever needed: the daemon loads,
        probes and plans with nothing else (a bundle without one falls back to its full graph)."""
        return ("tactile",) if "tactile" in self.manifest.graphs else ("full",)


def bundle_name(sb: StudyBundle) -> str:
    return sb.key


def study_sources(config: KioskConfig, study_bundles: StudyBundles):
    """The daemon's `bundle_sources`: exactly the study's bundles (verified once by `open_study_bundles`), each
    served under `<condition>:<garment>`."""
    inf = config.inference

    def load(sb: StudyBundle) -> LoadedBundle:
        return _ConditionBundle(sb, threads=inf.threads, providers=inf.providers, precisions=inf.precisions,
                                source=f"study:{sb.path}")

    return lambda: [(f"study:{sb.path}", lambda sb=sb: load(sb)) for sb in study_bundles.items.values()]


class DaemonRenderer:
    """Puts study scenes on the device through the daemon and waits until the device holds them."""

    def __init__(self, daemon: KioskDaemon, bundles: StudyBundles) -> None:
        self.daemon = daemon
        self.bundles = bundles

    def screen(self) -> tuple[int, int]:
        try:
            info = self.daemon.device.display.info
        except Exception as exc:  # noqa: BLE001 - the bridge raises its own LinkError before open
            raise StudyError(f"the haptic device is not connected ({exc}); the study needs it") from None
        return (int(info.panel_w), int(info.panel_h))

    def render(self, scene: Scene) -> Rendered:
        result = self.daemon.show(scene, {}, client="study", timeout_s=30.0)
        for pp in result.plan.panels:
            if pp.graph not in ("tactile", "none"):
                raise StudyError(f"panel {pp.panel}: the planner chose the {pp.graph} graph; a study trial must run "
                                 "tactile inference only")
        bad = [f"{p.panel}: {p.notice or p.status}" for p in result.panels if p.status != "ok"]
        if bad:
            raise StudyError("no friction map for " + "; ".join(bad))
        commit = self.daemon.wait_commit(result.device_frame, COMMIT_TIMEOUT_S)
        if commit is None or commit.status != "committed":
            raise StudyError(f"the haptic device did not take the trial's friction frame "
                             f"({commit.status if commit else 'no commit'}); is it connected?")
        placements = {}
        for pp in result.plan.panels:
            pl = pp.placement
            if pl is None:
                raise StudyError(f"panel {pp.panel} has no reference placement")
            placements[pp.panel] = {"scale": pl.scale, "x": pl.x, "y": pl.y, "size": list(pl.size)}
        return Rendered(placements=placements, frame=result.device_frame)

    def clear(self) -> None:
        """Blank the device: a scene whose only panel has nothing drawn yet (an empty, valid frame)."""
        any_bundle = next(iter(self.bundles.items.values()))
        w, h = self.screen()
        scene = Scene(panels=(Panel("blank", (0, 0, w, h), bundle_name(any_bundle), visual="none",
                                    tactile="model", sketch="strokes"),), screen=(w, h))
        result = self.daemon.show(scene, {"blank": SketchInput()}, client="study", timeout_s=30.0)
        self.daemon.wait_commit(result.device_frame, COMMIT_TIMEOUT_S)


def control_socket_of(config: StudyConfig) -> Path:
    """The operator socket: the kiosk config's control.socket, else `<log>.sock` beside the study log."""
    doc, _ = _kiosk_doc(config)
    sock = (doc.get("control") or {}).get("socket") if isinstance(doc.get("control"), dict) else None
    return Path(sock) if sock else config.log.with_suffix(".sock")


def _kiosk_doc(config: StudyConfig) -> tuple[dict, Path]:
    """The daemon's config document (inline mapping or YAML file) and the folder its relative paths start from."""
    if config.kiosk is None:
        return {}, config.base_dir
    if isinstance(config.kiosk, dict):
        return dict(config.kiosk), config.base_dir
    path = Path(config.kiosk)
    doc = loader.load_yaml(path, error=StudyConfigError, what="the study's kiosk config")
    ctl = doc.get("control")
    if isinstance(ctl, dict) and ctl.get("socket") and not Path(ctl["socket"]).is_absolute():
        doc = {**doc, "control": {**ctl, "socket": str(path.parent / ctl["socket"])}}
    return doc, path.parent


def kiosk_config_for(config: StudyConfig, bundles: StudyBundles, *, port: int | None = None,
                     control_socket: Path | None = None, device: str | None = None) -> KioskConfig:
    """The daemon's config in study mode: serves exactly the study's bundles, with the operator socket set."""
    doc, base = _kiosk_doc(config)
    doc["bundles"] = [str(sb.path) for sb in bundles.items.values()]
    doc["store"] = {**(doc.get("store") or {}), "root": None}
    doc["control"] = {**(doc.get("control") or {}), "socket": str(control_socket or control_socket_of(config))}
    if port is not None:
        doc["server"] = {**(doc.get("server") or {}), "port": port}
    if device == "emulated":
        doc["device"] = {**(doc.get("device") or {}), "type": "emulated"}
    return config_from_mapping(doc, base_dir=base)


class StudyRuntime:
    """Everything `vtkiosk study run` holds, started and stopped in order."""

    def __init__(self, config: StudyConfig, *, port: int | None = None, control_socket: Path | None = None,
                 device: str | None = None) -> None:
        self.config = config
        self.bundles = open_study_bundles(config)           # everything checked before anything is written
        self.daemon: KioskDaemon | None = None
        self.service: StudyService | None = None
        try:
            self.log = StudyLog.open(config.log, config.id)
        except BaseException:
            self.bundles.close()
            raise
        try:
            kcfg = kiosk_config_for(config, self.bundles, port=port, control_socket=control_socket, device=device)
            self.daemon = KioskDaemon(kcfg, bundle_sources=study_sources(kcfg, self.bundles))
            self.daemon.start()
            served = set(self.daemon.bundles)
            missing = sorted(bundle_name(sb) for sb in self.bundles.items.values() if bundle_name(sb) not in served)
            if missing:
                raise StudyError(f"the daemon could not serve study bundle(s) {', '.join(missing)}: "
                                 f"{self.daemon.status().get('last_reload')}")
            self.service = StudyService(config, self.log, self.bundles, DaemonRenderer(self.daemon, self.bundles))
            self.daemon.server.route("GET", "/api/study/", self.service.http_get)
            self.daemon.server.route("POST", "/api/study/", self.service.http_post)
            self.daemon.add_control_handler("study.", self.service.control)
            self.daemon.add_health_check("study_log", storage_check(config.log, self.service.log_error))
            self.service.start_timer()
        except BaseException:
            self.close()
            raise

    @property
    def url(self) -> str:
        assert self.daemon is not None
        return self.daemon.server.url + "study"

    def close(self) -> None:
        if self.service is not None:
            self.service.close()
        if self.daemon is not None:
            self.daemon.stop()
        self.bundles.close()
        self.log.close()


def run_study(config_path: Path, *, port: int | None = None, control_socket: Path | None = None,
              device: str | None = None) -> int:
    config = load_study_config(config_path)
    configure_logging(level="INFO")   # the journal under systemd, else stderr
    runtime = StudyRuntime(config, port=port, control_socket=control_socket, device=device)
    with on_signals() as signals:
        assert runtime.service is not None and runtime.daemon is not None
        say_line(f"study {config.id}: page {runtime.url}")
        say_line(f"study {config.id}: control socket {runtime.daemon.config.control.socket}")
        say_line(f"study {config.id}: log {config.log}")
        active = runtime.service.status().get("active")
        if active:
            say_line(f"study {config.id}: resumed {active['participant']} session {active['session']} at trial "
                     f"{active['trial']}")
        try:
            while not signals.stop:
                signals.wait(1.0)
        finally:
            # A shutdown that stalls leaves every thread's stack on stderr (the journal) instead of a silent hang.
            faulthandler.dump_traceback_later(SHUTDOWN_STACKS_AFTER_S, exit=False, file=sys.stderr)
            try:
                runtime.close()
            finally:
                faulthandler.cancel_dump_traceback_later()
    print(f"study {config.id}: stopped", file=sys.stderr, flush=True)
    return 0

