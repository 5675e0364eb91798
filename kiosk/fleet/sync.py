"""`vtkiosk fleet sync` on a kiosk: refresh the TUF metadata with python-tuf's ngclient, download the bundles meant
for this kiosk, and hand each to the bundle store (verify, install, health-gated activate, roll back).

Two layers must both hold: TUF decides whether the repository's metadata and files are the ones the operator's
keys signed, fresh and consistent (rollback, freeze, mix-and-match, tampered or endless targets); the store then
checks the bundle's own signature against the kiosk's trusted bundle keys, its hashes, and probes it. Unsigned
bundles are never installed from a fleet, whatever `store.allow_unsigned` says.

Per garment the kiosk takes the newest release that is on a channel it reads, reaches its rollout bucket, is not
withdrawn and fits its runtime version. It never goes below its active version; the one way back is an operator's
signed withdrawal of the active version, and then only to a version that is already installed. A version that is
installed but not active (the daemon refused it, or an operator rolled back by hand) is left alone. Nothing here
touches the active bundle until the new one is verified and installed, so the kiosk keeps serving throughout.
"""
from __future__ import annotations

import contextlib
import fcntl
import logging
import os
import random
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib import metadata as importlib_metadata
from pathlib import Path

from tuf.api import exceptions as tuf_errors
from tuf.ngclient import Updater, UpdaterConfig
from tuf.ngclient.urllib3_fetcher import Urllib3Fetcher
from urllib3.exceptions import HTTPError as TransportError

from kiosk.bundle.manifest import BundleError
from kiosk.bundle.store import BundleStore, StoreError
from kiosk.bundle.version import compare, is_older, parse_version
from kiosk.fleet import state as fleet_state
from kiosk.fleet.layout import READS, FleetError, Release, RefusedError, index_path, parse_index, \
    release_from_custom
from kiosk.service.config import FleetConfig

log = logging.getLogger(__name__)


def runtime_version() -> str:
    try:
        return importlib_metadata.version("vtkiosk")
    except importlib_metadata.PackageNotFoundError:
        return "0"


def explain(exc: BaseException) -> str:
    """One line: what TUF refused and what it most likely means."""
    why = " ".join(str(exc).split())
    if not why:  # ngclient's download errors often carry their reason only as the cause
        cause = exc.__cause__ or exc.__context__
        why = type(exc).__name__ + (f" ({' '.join(str(cause).split())})" if cause is not None else "")
    if isinstance(exc, tuf_errors.BadVersionNumberError):
        return f"{why} (rollback: the repository served older metadata than this kiosk has already seen)"
    if isinstance(exc, tuf_errors.ExpiredMetadataError):
        return f"{why} (freeze: the metadata has expired; the repository is not refreshed, or replays old files)"
    if isinstance(exc, tuf_errors.UnsignedMetadataError):
        return f"{why} (not signed by the keys this kiosk trusts for that role: forged, or a revoked key)"
    if isinstance(exc, tuf_errors.LengthOrHashMismatchError):
        return f"{why} (the file is not the one the signed metadata describes: tampered, or mixed and matched)"
    if isinstance(exc, tuf_errors.DownloadLengthMismatchError):
        return f"{why} (endless data: the server sent more than the signed length)"
    return why


@dataclass
class GarmentResult:
    garment: str
    outcome: str
    detail: str
    offered: str | None = None
    active: str | None = None

    def to_json(self) -> dict:
        return {"garment": self.garment, "outcome": self.outcome, "detail": self.detail, "offered": self.offered,
                "active": self.active}


@dataclass
class SyncReport:
    result: str  # ok | offline | refused | error
    detail: str
    garments: list[GarmentResult] = field(default_factory=list)
    metadata: dict = field(default_factory=dict)
    attempts: int = 1

    def to_json(self) -> dict:
        return {"result": self.result, "detail": self.detail, "garments": [g.to_json() for g in self.garments],
                "metadata": self.metadata, "attempts": self.attempts}


class _Fetcher(Urllib3Fetcher):
    """ngclient's own fetcher, remembering the last URL it asked for, so a refusal can name the file."""

    last_url = ""

    def _fetch(self, url: str):
        self.last_url = url
        return super()._fetch(url)


def activate_gated(store: BundleStore, garment: str, version: str, control_socket: Path | None, *,
                   allow_downgrade: bool = False) -> tuple[bool, str]:
    """Activate, then ask the running daemon to load it; if the daemon refuses (it failed to load or to answer its
    probe in budget), put the store back as it was. (True, how) or (False, the daemon's reason). Only a signed
    withdrawal may go to an older version (`allow_downgrade`): the operator's emergency rollback."""
    from kiosk.ops.control import ControlError, NoDaemonError, send_control

    before = store.links(garment)
    store.activate(garment, version, allow_downgrade=allow_downgrade)
    if control_socket is None:
        return True, "activated (no daemon control socket configured)"
    try:
        reply = send_control(control_socket, {"op": "reload"}, timeout_s=120.0)
    except NoDaemonError:
        return True, "activated; no daemon running, it serves it when it starts"
    except ControlError as exc:
        store.restore(garment, current=before[0], previous=before[1])
        return False, f"the daemon could not be asked to reload ({exc}); store switched back"
    mine = [e for e in reply.get("kept", []) + reply.get("failed", [])
            if e.get("garment") == garment or str(e.get("source", "")).startswith(f"store:{garment}/")]
    if mine:
        store.restore(garment, current=before[0], previous=before[1])
        return False, "the daemon refused it: " + "; ".join(str(e.get("reason", "?")) for e in mine)
    return True, "activated; the daemon reloaded"


class FleetSync:
    """One kiosk's sync. `sleep` and `rand` are injectable so tests need not wait for the backoff."""

    def __init__(self, cfg: FleetConfig, store: BundleStore, *, control_socket: Path | None = None,
                 runtime: str | None = None, sleep: Callable[[float], None] = time.sleep,
                 rand: Callable[[], float] = random.random):
        if not cfg.enabled:
            raise FleetError("no fleet.url in the kiosk config: this kiosk takes no part in a fleet")
        self.cfg = cfg
        # Both layers always: a fleet never installs an unsigned bundle.
        self.store = BundleStore(store.root, store.trusted_keys_dir, allow_unsigned=False,
                                 probe_threads=store.probe_threads, lock_timeout_s=store.lock_timeout_s,
                                 limits=store.limits)
        self.control_socket = control_socket
        self.runtime = runtime or runtime_version()
        self._sleep, self._rand = sleep, rand
        self.state_dir = Path(cfg.state_dir)
        self.state_path = self.state_dir / fleet_state.STATE_FILE

    # -- the run -------------------------------------------------------------------------------------------------
    def run(self) -> SyncReport:
        """Sync, retrying with exponential backoff while the repository does not answer; record the result."""
        self.state_dir.mkdir(parents=True, exist_ok=True)
        with self._single():
            report = self._once()
            attempt = 1
            while report.result == "offline" and attempt < self.cfg.attempts:
                delay = min(self.cfg.max_backoff_s, self.cfg.backoff_s * 2 ** (attempt - 1))
                delay *= 0.5 + 0.5 * self._rand()  # jitter: forty kiosks do not retry in step
                log.warning("fleet sync: %s; retrying in %.1f s (attempt %d of %d)", report.detail, delay,
                            attempt + 1, self.cfg.attempts)
                self._sleep(delay)
                attempt += 1
                report = self._once()
            report.attempts = attempt
            fleet_state.record(self.state_path, report.to_json())
        self._log(report)
        return report

    @contextlib.contextmanager
    def _single(self):
        fd = os.open(self.state_dir / ".sync.lock", os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o640)
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                raise FleetError(f"another fleet sync is running (lock {self.state_dir / '.sync.lock'})") from None
            yield
        finally:
            os.close(fd)

    def _log(self, report: SyncReport) -> None:
        level = logging.INFO if report.result == "ok" else logging.WARNING
        log.log(level, "fleet sync %s: %s", report.result, report.detail,
                extra={"FLEET_RESULT": report.result, "FLEET_ATTEMPTS": report.attempts})
        for g in report.garments:
            lvl = logging.WARNING if g.outcome.startswith(("refused", "failed", "rolled", "withdrawn", "error")) \
                else logging.INFO
            log.log(lvl, "fleet %s: %s: %s", g.garment, g.outcome, g.detail,
                    extra={"GARMENT": g.garment, "FLEET_OUTCOME": g.outcome, "OFFERED": g.offered or "",
                           "ACTIVE": g.active or ""})

    def _updater(self, downloads: Path) -> Updater:
        try:
            anchor = Path(self.cfg.root).read_bytes()
        except OSError as exc:
            raise FleetError(f"fleet.root {self.cfg.root}: cannot read the trust anchor ({exc.strerror})") from None
        meta = self.state_dir / "metadata"
        meta.mkdir(parents=True, exist_ok=True)
        base = self.cfg.url if self.cfg.url.endswith("/") else self.cfg.url + "/"
        self._fetcher = _Fetcher(socket_timeout=int(max(1, self.cfg.timeout_s)),
                                 app_user_agent=f"vtkiosk/{self.runtime}")
        return Updater(str(meta), base + "metadata/", str(downloads), base + "targets/", fetcher=self._fetcher,
                       config=UpdaterConfig(app_user_agent=f"vtkiosk/{self.runtime}"), bootstrap=anchor)

    def _once(self) -> SyncReport:
        downloads = self.state_dir / "downloads"
        shutil.rmtree(downloads, ignore_errors=True)
        downloads.mkdir(parents=True)
        try:
            try:
                updater = self._updater(downloads)
                updater.refresh()
                releases = self._releases(updater, downloads)
            except (tuf_errors.RepositoryError, tuf_errors.DownloadLengthMismatchError) as exc:
                return SyncReport("refused", f"refused {self._last_file()}: {explain(exc)}",
                                  metadata=self._trusted_metadata())
            except RefusedError as exc:
                return SyncReport("refused", str(exc), metadata=self._trusted_metadata())
            except (tuf_errors.DownloadError, TransportError, OSError) as exc:
                return SyncReport("offline", f"repository {self.cfg.url} unreachable ({self._last_file()}): "
                                  f"{explain(exc)}; keeping the installed bundles", metadata=self._trusted_metadata())
            results = [self._garment(updater, g, rs, downloads) for g, rs in sorted(releases.items())]
        finally:
            shutil.rmtree(downloads, ignore_errors=True)
        worst = "ok"
        if any(r.outcome == "failed_download" for r in results):
            worst = "offline"
        if any(r.outcome.startswith("refused") for r in results):
            worst = "refused"
        if any(r.outcome == "error" for r in results):
            worst = "error"
        changed = [f"{r.garment} {r.outcome} {r.offered or ''}".rstrip() for r in results
                   if r.outcome not in ("up_to_date", "not_offered")]
        detail = "; ".join(changed) if changed else f"{len(results)} garment(s) up to date"
        # The metadata was verified fresh even when a garment's bundle was then refused: that is its age.
        return SyncReport(worst, detail, results, {**self._trusted_metadata(), "verified": True})

    def _last_file(self) -> str:
        url = getattr(getattr(self, "_fetcher", None), "last_url", "")
        base = self.cfg.url if self.cfg.url.endswith("/") else self.cfg.url + "/"
        return url[len(base):] if url.startswith(base) else (url or "the repository's metadata")

    def _trusted_metadata(self) -> dict:
        """Version and expiry of the timestamp and snapshot this kiosk trusts now (from its verified cache)."""
        from tuf.api.metadata import Metadata

        out = {}
        for role in ("timestamp", "snapshot"):
            try:
                signed = Metadata.from_file(str(self.state_dir / "metadata" / f"{role}.json")).signed
            except Exception:  # noqa: BLE001 - nothing trusted yet is a normal state, not an error
                continue
            out[f"{role}_version"] = signed.version
            out[f"{role}_expires"] = signed.expires.isoformat()
        return out

    # -- what the repository offers ------------------------------------------------------------------------------
    def _releases(self, updater: Updater, downloads: Path) -> dict[str, list[tuple[Release, object]]]:
        by_garment: dict[str, list[tuple[Release, object]]] = {}
        for channel in READS[self.cfg.channel]:
            info = updater.get_targetinfo(index_path(channel))
            if info is None:
                raise RefusedError(f"channel {channel} has no signed index ({index_path(channel)})")
            local = updater.download_target(info, str(downloads / f"{channel}-index.json"))
            for path in parse_index(channel, Path(local).read_bytes()):
                t = updater.get_targetinfo(path)
                if t is None:
                    raise RefusedError(f"the {channel} index lists {path}, which no signed metadata describes")
                r = release_from_custom(path, t.custom)
                by_garment.setdefault(r.garment, []).append((r, t))
        return by_garment

    # -- one garment ---------------------------------------------------------------------------------------------
    def _garment(self, updater: Updater, garment: str, releases: list[tuple[Release, object]],
                 downloads: Path) -> GarmentResult:
        kiosk = self.cfg.kiosk_id
        active = self.store.active().get(garment)
        active_v = active.version if active else None
        withdrawn = {r.version for r, _ in releases if r.withdrawn}
        eligible = [(r, t) for r, t in releases if r.reaches(kiosk) and not is_older(self.runtime, r.min_runtime)]
        best = None
        for r, t in eligible:
            if best is None or compare(r.version, best[0].version) > 0:
                best = (r, t)
        res = GarmentResult(garment, "up_to_date", "", best[0].version if best else None, active_v)
        try:
            if active_v is not None and active_v in withdrawn and (best is None or
                                                                   compare(best[0].version, active_v) <= 0):
                return self._fall_back(res, garment, active_v, withdrawn)
            if best is None:
                needs = [r for r, _ in releases if r.reaches(kiosk) and is_older(self.runtime, r.min_runtime)]
                if needs:
                    res.outcome = "needs_runtime"
                    res.detail = (f"{garment} {needs[0].version} needs runtime {needs[0].min_runtime}; this kiosk "
                                  f"runs {self.runtime}")
                else:
                    res.outcome, res.detail = "not_offered", "nothing for this kiosk's channel and rollout bucket"
                return res
            want, info = best
            if active_v is not None and compare(want.version, active_v) < 0:
                res.outcome = "refused_downgrade"
                res.detail = (f"refused {garment} {want.version}: older than the active {active_v} (a kiosk never "
                              "downgrades; withdraw the active version to go back)")
                return res
            if active_v is not None and compare(want.version, active_v) == 0:
                res.detail = f"{garment} {active_v} is active"
                return res
            installed = {s.version for s in self.store.list() if s.garment == garment}
            if want.version in installed:
                res.outcome = "installed_inactive"
                res.detail = (f"{garment} {want.version} is installed but not active (the daemon refused it, or an "
                              "operator rolled back); left alone: `vtkiosk bundle activate` to retry it")
                return res
            return self._install(updater, res, want, info, downloads)
        except (BundleError, StoreError) as exc:
            res.outcome, res.detail = "error", f"{garment}: {exc}"
            return res

    def _install(self, updater: Updater, res: GarmentResult, want: Release, info, downloads: Path) -> GarmentResult:
        dest = downloads / f"{want.garment}-{want.version}.vtb"
        try:
            local = Path(updater.download_target(info, str(dest)))
        except (tuf_errors.RepositoryError, tuf_errors.DownloadLengthMismatchError) as exc:
            res.outcome = "refused_target"
            res.detail = f"refused {want.path}: {explain(exc)}"
            return res
        except (tuf_errors.DownloadError, TransportError, OSError) as exc:
            res.outcome = "failed_download"
            res.detail = f"download of {want.path} failed: {explain(exc)}; will retry"
            return res
        try:
            stored = self.store.install(local)
        except BundleError as exc:
            res.outcome = "refused_bundle"
            res.detail = f"refused {want.path}: the bundle itself failed verification: {' '.join(str(exc).split())}"
            return res
        finally:
            local.unlink(missing_ok=True)
        if (stored.garment, stored.version) != (want.garment, want.version):
            res.outcome = "refused_bundle"
            res.detail = (f"refused {want.path}: the bundle inside is {stored.garment} {stored.version}; "
                          "left installed but inactive")
            return res
        ok, how = activate_gated(self.store, want.garment, want.version, self.control_socket)
        res.outcome = "installed" if ok else "rolled_back"
        res.detail = f"{want.garment} {want.version}: {how}"
        res.active = self.store.links(want.garment)[0]
        return res

    def _fall_back(self, res: GarmentResult, garment: str, active_v: str, withdrawn: set[str]) -> GarmentResult:
        candidates = [s.version for s in self.store.list()
                      if s.garment == garment and s.version not in withdrawn and s.version != active_v]
        if not candidates:
            res.outcome = "withdrawn_kept"
            res.detail = (f"{garment} {active_v} was withdrawn, but no other version is installed; still serving "
                          "it until a newer one is published")
            return res
        target = max(candidates, key=lambda v: (compare(v, active_v) < 0, parse_version(v)))
        ok, how = activate_gated(self.store, garment, target, self.control_socket, allow_downgrade=True)
        res.outcome = "withdrawn_rollback" if ok else "withdrawn_kept"
        res.detail = f"{garment} {active_v} was withdrawn by the operator; back to {target}: {how}"
        res.offered = target
        res.active = self.store.links(garment)[0]
        return res

