"""`vtkiosk study run`: the kiosk daemon in study mode, with the study service mounted on it.

The daemon (kiosk.service.daemon.KioskDaemon) does what it always does: plans scenes, runs ONNX Runtime, turns tactile
output into friction maps and puts them on the haptic device. Study mode changes two things:
- what it serves: every (condition, garment) bundle of the study, each under the name `<condition>:<garment>`
  (the conditions share garment ids, so the garment id alone cannot name them). `study_sources` supplies these as
  the daemon's bundle candidates, so they are verified, probed and reported by the daemon's own reload path;
- what is shown: the study service builds each trial's two-panel scene (haptic study: reference visual, model
  tactile, the same half; visual study: each side's model visual, no tactile) and calls `KioskDaemon.show`; the
  planner runs the tactile (or visual) graphs only. Familiarisation textures go to the device as ready friction
  maps. The study page is at /study, the researcher's live view at /study-operator, the API under /api/study/,
  the operator's ops (`study.start|status|stop|next|skip|withdraw`) on the daemon's control socket.
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
from kiosk.inference.render import Texture
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

    def __init__(self, sb: StudyBundle, *, kind: str = "haptic", **kwargs: Any) -> None:
        self.study_name = bundle_name(sb)
        self.study_kind = kind
        super().__init__(sb.bundle, **kwargs)

    @property
    def garment_id(self) -> str:
        return self.study_name

    def graphs(self) -> tuple[str, ...]:
        """A haptic trial shows the reference visual, so only the tactile graph is ever needed (a visual trial: only
        the visual graph): the daemon loads, probes and plans with nothing else (a bundle without that graph falls
        back to its full graph)."""
        want = "tactile" if self.study_kind == "haptic" else "visual"
        return (want,) if want in self.manifest.graphs else ("full",)


def bundle_name(sb: StudyBundle) -> str:
    return sb.key


def study_sources(config: KioskConfig, study_bundles: StudyBundles, kind: str = "haptic"):
    """The daemon's `bundle_sources`: exactly the study's bundles (verified once by `open_study_bundles`), each
    served under `<condition>:<garment>`."""
    inf = config.inference

    def load(sb: StudyBundle) -> LoadedBundle:
        return _ConditionBundle(sb, kind=kind, threads=inf.threads, providers=inf.providers,
                                precisions=inf.precisions, source=f"study:{sb.path}")

    return lambda: [(f"study:{sb.path}", lambda sb=sb: load(sb)) for sb in study_bundles.items.values()]


class _ReadyFriction:
    """A friction texture that needs no model (familiarisation), in the shape the device output takes."""

    ms = 0.0
    nonfinite = 0

    def __init__(self, texture: Texture) -> None:
        self.panel = texture.panel
        self._texture = texture
        self.rect = texture.rect

    def texture(self) -> Texture:
        return self._texture


class DaemonRenderer:
    """Puts study scenes on the device through the daemon and waits until the device holds them."""

    def __init__(self, daemon: KioskDaemon, bundles: StudyBundles, kind: str = "haptic") -> None:
        self.daemon = daemon
        self.bundles = bundles
        self.kind = kind

    def screen(self) -> tuple[int, int]:
        try:
            info = self.daemon.device.display.info
        except Exception as exc:  # noqa: BLE001 - the bridge raises its own LinkError before open
            raise StudyError(f"the haptic device is not connected ({exc}); the study needs it") from None
        return (int(info.panel_w), int(info.panel_h))

    def render(self, scene: Scene) -> Rendered:
        result = self.daemon.show(scene, {}, client="study", timeout_s=30.0)
        want = "tactile" if self.kind == "haptic" else "visual"
        # A single-branch bundle (the paper's baselines) has only the full graph: it is the cheapest way to its
        # tactile or visual output, and the unused output is dropped. Anything else would be wasted inference.
        separate = {sb.key: want in sb.bundle.manifest.graphs for sb in self.bundles.items.values()}
        for pp in result.plan.panels:
            if pp.graph not in (want, "none") and not (pp.graph == "full" and not separate.get(pp.bundle, True)):
                raise StudyError(f"panel {pp.panel}: the planner chose the {pp.graph} graph; a {self.kind} study "
                                 f"trial must run {want} inference only (the full graph only for a bundle "
                                 "without separate branches)")
        bad = [f"{p.panel}: {p.notice or p.status}" for p in result.panels if p.status != "ok"]
        if bad:
            raise StudyError(f"no {'friction map' if self.kind == 'haptic' else 'visual output'} for "
                             + "; ".join(bad))
        if self.kind == "visual":
            return self._visuals(result)
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

    @staticmethod
    def _visuals(result) -> Rendered:
        """Each panel's visual output (RGBA at the network grid) as PNG, and the screen rectangle it fills."""
        import cv2

        placements, images = {}, {}
        for pr in result.panels:
            if pr.visual is None or pr.plan.region is None:
                raise StudyError(f"panel {pr.panel}: the model returned no visual output")
            ok, buf = cv2.imencode(".png", cv2.cvtColor(pr.visual, cv2.COLOR_RGBA2BGRA))
            if not ok:
                raise StudyError(f"panel {pr.panel}: the visual output could not be encoded")
            placements[pr.panel] = {"rect": list(pr.plan.region)}
            images[pr.panel] = buf.tobytes()
        return Rendered(placements=placements, frame=result.frame, images=images)

    def friction(self, rect: tuple[int, int, int, int], pixels) -> None:
        """Put a ready friction map at `rect` on the device and wait until it holds it."""
        x, y, _, _ = rect
        frame = self.daemon.put_friction([_ReadyFriction(Texture("familiarisation", pixels, x, y))])
        commit = self.daemon.wait_commit(frame, COMMIT_TIMEOUT_S)
        if commit is None or commit.status != "committed":
            raise StudyError(f"the haptic device did not take the familiarisation texture "
                             f"({commit.status if commit else 'no commit'}); is it connected?")

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
            self.daemon = KioskDaemon(kcfg, bundle_sources=study_sources(kcfg, self.bundles, config.kind))
            self.daemon.start()
            served = set(self.daemon.bundles)
            missing = sorted(bundle_name(sb) for sb in self.bundles.items.values() if bundle_name(sb) not in served)
            if missing:
                raise StudyError(f"the daemon could not serve study bundle(s) {', '.join(missing)}: "
                                 f"{self.daemon.status().get('last_reload')}")
            self.service = StudyService(config, self.log, self.bundles,
                                        DaemonRenderer(self.daemon, self.bundles, config.kind))
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

