"""The bundles the kiosk serves: where they come from, loading and probing them, and swapping them in on reload.

A reload loads every candidate beside what is served, probes the new ones, and swaps per garment only when the new
bundle passes; a garment whose new bundle fails keeps its old one. The served set is a dict replaced as a whole
(one reference assignment), so a job in flight finishes on the bundle it started with; a swapped-out bundle stays
open for `RETIRE_GRACE_S` before it is closed.
"""
from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

from kiosk.bundle.archive import open_bundle, verify_directory
from kiosk.bundle.manifest import BundleError
from kiosk.contract.errors import KioskError
from kiosk.contract.graph import grid_floor
from kiosk.inference.backends import ENGINES
from kiosk.inference.engine import LoadedBundle
from kiosk.inference.scene import choose_graph
from kiosk.ops.health import CheckResult
from kiosk.service.config import KioskConfig
from kiosk.service.metrics import ServiceMetrics

log = logging.getLogger(__name__)
RETIRE_GRACE_S = 10.0  # a swapped-out bundle stays open this long for jobs that started on it

Sources = Callable[[], list[tuple[str, Callable[[], LoadedBundle]]]]
OUTCOMES = ("swapped", "loaded", "kept", "unchanged", "removed", "failed")


@dataclass
class Candidates:
    """What loading every candidate produced: bundles that passed their probe, and the report so far."""

    passed: dict[str, LoadedBundle] = field(default_factory=dict)
    seen: set[str] = field(default_factory=set)        # garments some candidate loaded for (probe passed or not)
    report: dict[str, list] = field(default_factory=lambda: {k: [] for k in OUTCOMES})


def plan_swap(current: Mapping[str, object], passed: Mapping[str, object], seen: set[str],
              any_failed: bool) -> tuple[dict, list[str]]:
    """(what to serve next, garments removed). New bundles replace old ones per garment; a garment no candidate
    loaded for goes only when every candidate loaded (a failed one might have been it); never swap to nothing."""
    removed = [] if any_failed else [g for g in current if g not in seen]
    serving = {g: b for g, b in current.items() if g not in removed}
    serving.update(passed)
    if not serving and current:
        return dict(current), []
    return serving, removed


class BundleSet:
    """The served bundles and their reloads. `sources` replaces the store + configured bundles as what to serve
    (the A/B study serves each condition's bundle under its own name); it is asked again on every reload."""

    def __init__(self, config: KioskConfig, metrics: ServiceMetrics, sources: Sources | None = None):
        self.config = config
        self.metrics = metrics
        self._sources = sources
        self.serving: dict[str, LoadedBundle] = {}  # replaced whole, never mutated: readers take it as a snapshot
        self.workdir: Path | None = None            # where bundle archives are unpacked
        self.last_reload: dict | None = None
        self._retired: list[tuple[float, LoadedBundle]] = []
        self._lock = threading.Lock()

    # -- where bundles come from -----------------------------------------------------------------------------------
    def _make(self, bundle, source: str, owned: Path | None = None) -> LoadedBundle:
        inf = self.config.inference
        return LoadedBundle(bundle, threads=inf.threads, providers=inf.providers, precisions=inf.precisions,
                            owned_dir=owned, source=source, engine=inf.engine.type,
                            auto_max_side=inf.max_resolution, auto_runs=inf.engine.auto_runs,
                            preview_threads=inf.preview_threads, settings=inf.session_settings())

    def candidates(self) -> list[tuple[str, Callable[[], LoadedBundle]]]:
        """(source description, loader) for every bundle the kiosk should serve now."""
        if self._sources is not None:
            return self._sources()
        store = self.config.store
        trusted = None
        if store.trusted_keys is not None:
            from kiosk.bundle.signature import load_trusted_keys

            trusted = load_trusted_keys(store.trusted_keys)
        out: list[tuple[str, Callable[[], LoadedBundle]]] = []
        if store.root is not None:
            from kiosk.bundle.store import BundleStore

            active = BundleStore(store.root, store.trusted_keys, allow_unsigned=store.allow_unsigned).active()
            for garment, stored in sorted(active.items()):
                source = f"store:{garment}/{stored.version}"
                out.append((source, lambda stored=stored, source=source: self._make(
                    verify_directory(stored.path, trusted, allow_unsigned=store.allow_unsigned), source)))
        for path in self.config.bundles:
            def load(path=path) -> LoadedBundle:
                if Path(path).is_dir():
                    return self._make(verify_directory(path, trusted, allow_unsigned=store.allow_unsigned), str(path))
                assert self.workdir is not None, "bundle archives are opened after start()"
                b = open_bundle(path, trusted, workdir=self.workdir, allow_unsigned=store.allow_unsigned)
                return self._make(b, str(path), owned=b.root)
            out.append((str(path), load))
        return out

    def probe(self, lb: LoadedBundle, *, enforce_budget: bool = True) -> dict:
        """Load every graph and run it at the largest grid the planner will use; the best of three runs must be
        within the latency budget (`enforce_budget`; at start-up, with nothing else to serve, an overrun is logged
        and the health check reports the loop's real latency instead)."""
        inf = self.config.inference
        budget = inf.latency_budget_ms
        results = {}
        for kind in lb.graphs():
            cw, ch = lb.cap(kind)
            grid = (grid_floor(min(cw, inf.max_resolution)), grid_floor(min(ch, inf.max_resolution)))
            preview = (min(grid[0], inf.preview_max_resolution), min(grid[1], inf.preview_max_resolution))
            runs = lb.warm((kind,), [preview, grid, grid, grid, grid])  # the first run at `grid` allocates
            if lb.lane_of("preview") == "preview" and kind == choose_graph(("visual",), lb.graphs()):
                lb.warm((kind,), [preview], lane="preview")  # the one graph previews run, in their own lane
            ms = min(r[2] for r in runs[2:])
            results[kind] = {"grid": list(grid), "ms": round(ms, 1)}
            if ms > budget:
                msg = (f"bundle {lb.garment_id}: the {kind} graph takes {ms:.0f} ms at {grid[0]}x{grid[1]}, over the "
                       f"{budget:.0f} ms latency budget")
                if enforce_budget:
                    raise BundleError(msg)
                log.warning("%s; serving it anyway (nothing else to serve)", msg)
                results[kind]["over_budget"] = True
        return results

    # -- reload ------------------------------------------------------------------------------------------------------
    def reload(self) -> dict:
        """Load what should be served beside what is served, probe it, and swap per garment only when it passes.
        Returns what happened, with reasons."""
        with self._lock:
            self._close_retired()
            current = self.serving
            try:
                sources = self.candidates()
            except KioskError as exc:
                report = Candidates().report
                report["failed"].append({"source": "config", "reason": str(exc)})
                self.metrics.reloads.inc(result="failed")
                self.last_reload = report
                return report
            found = self._load_all(sources, current)
            serving, removed = plan_swap(current, found.passed, found.seen,
                                         any_failed=bool(found.report["failed"]))
            self.serving = serving  # the swap
            for lb in found.passed.values():
                self._record_engine(lb)
            found.report["removed"].extend(removed)
            now = time.monotonic()
            self._retired.extend((now, current[g]) for g in [*found.passed, *removed] if g in current)
            r = found.report
            result = "swapped" if (r["swapped"] or r["loaded"] or removed) else \
                "kept" if (r["kept"] or r["failed"]) else "unchanged"
            return self._finish(r, result)

    def _load_all(self, sources, current: Mapping[str, LoadedBundle]) -> Candidates:
        out = Candidates()
        for source, load in sources:
            try:
                lb = load()
            except (KioskError, OSError) as exc:
                out.report["failed"].append({"source": source, "reason": str(exc)})
                log.warning("bundle %s not loaded: %s", source, exc)
                continue
            out.seen.add(lb.garment_id)
            old = current.get(lb.garment_id)
            if old is not None and old.key == lb.key:
                lb.close()
                out.report["unchanged"].append({"garment": lb.garment_id, "key": old.key})
                continue
            try:
                probe = self.probe(lb, enforce_budget=old is not None)
            except (KioskError, OSError) as exc:
                lb.close()
                entry = {"garment": lb.garment_id, "source": source, "reason": str(exc)}
                out.report["kept" if old is not None else "failed"].append(entry)
                log.warning("bundle %s failed its probe (%s); %s", source, exc,
                            f"keeping {old.key}" if old else "not serving it")
                continue
            out.passed[lb.garment_id] = lb
            entry = {"garment": lb.garment_id, "key": lb.key, "source": source, "probe": probe}
            if old is not None:
                out.report["swapped"].append({**entry, "replaced": old.key})
            else:
                out.report["loaded"].append(entry)
        return out

    def _finish(self, report: dict, result: str) -> dict:
        self.metrics.reloads.inc(result=result)
        report["serving"] = {g: b.key for g, b in sorted(self.serving.items())}
        self.last_reload = report
        log.info("reload: %s", json.dumps({k: v for k, v in report.items() if v}, default=str))
        return report

    def close_retired(self) -> None:
        """Close bundles swapped out long enough ago (between jobs; skipped while a reload runs)."""
        if self._retired and self._lock.acquire(blocking=False):
            try:
                self._close_retired()
            finally:
                self._lock.release()

    def _close_retired(self) -> None:
        now = time.monotonic()
        keep = []
        for at, b in self._retired:
            if now - at >= RETIRE_GRACE_S:
                b.close()
            else:
                keep.append((at, b))
        self._retired = keep

    def close(self) -> None:
        for b in list(self.serving.values()) + [b for _, b in self._retired]:
            b.close()
        self.serving, self._retired = {}, []

    # -- what operators see ------------------------------------------------------------------------------------------
    def check(self) -> CheckResult:
        serving = self.serving
        if not serving:
            return CheckResult(False, "no bundle loaded")
        return CheckResult(True, ", ".join(b.key.split("#")[0] for b in serving.values()))

    def _record_engine(self, lb: LoadedBundle) -> None:
        m = self.metrics
        for figures in (lb.engine_choice.figures if lb.engine_choice else []):
            if figures.ms_p50 is not None:
                m.engine_ms.set(figures.ms_p50, garment=lb.garment_id, engine=figures.engine)
                m.engine_err.set(figures.err_levels or 0.0, garment=lb.garment_id, engine=figures.engine)
        for engine in ENGINES:
            m.engine.set(1.0 if engine == lb.engine else 0.0, garment=lb.garment_id, engine=engine)

    def engine_info(self) -> dict:
        """Each garment's engine and, under engine: auto, the activation benchmark that chose it."""
        return {g: {"engine": b.engine, "choice": b.engine_choice.to_json() if b.engine_choice else None}
                for g, b in sorted(self.serving.items())}

    def scale_info(self) -> dict:
        """Both pitches: the panel's (config) and each bundle's (what its model learned at), and the ratio the
        planner infers at (grid px per screen px)."""
        panel = self.config.panel.describe()
        return {"panel": panel, "bundles": {g: {"pixel_pitch_mm": b.pixel_pitch_mm,
                                                "grid_per_screen_px": round(panel["pitch_mm"] / b.pixel_pitch_mm, 4)}
                                            for g, b in sorted(self.serving.items())}}


def failure_reason(report: dict) -> str:
    """One line naming each garment (or source) that a reload did not swap in, and why."""
    items = report["kept"] + report["failed"]
    return "; ".join(f"{e.get('garment') or e.get('source')}: {e['reason']}" for e in items)
