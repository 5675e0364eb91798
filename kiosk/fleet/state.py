"""The last sync's result on disk (`<state_dir>/state.json`), and what the daemon makes of it: a /healthz check
and section, and metrics. The sync job writes; the daemon only reads, so neither waits for the other.

The metadata's age counts from the last sync that verified fresh metadata (whatever it then did with the bundles).
The fleet check never fails: a kiosk whose repository is offline or whose metadata is stale still serves its
bundles well, and a failing check would stop the watchdog pings and get a healthy kiosk restarted. Its detail
(and the `fleet` section of /healthz) says how old the metadata is and what the last sync did.
"""
from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from datetime import datetime
from pathlib import Path

from kiosk.bundle.durable import atomic_write
from kiosk.ops.health import CheckResult

STATE_FILE = "state.json"
RESULTS = ("ok", "offline", "refused", "error")
OUTCOMES = ("installed", "up_to_date", "not_offered", "rolled_back", "withdrawn_rollback", "withdrawn_kept",
            "installed_inactive", "refused_downgrade", "refused_target", "refused_bundle", "failed_download",
            "needs_runtime", "error")


def load_state(path: Path) -> dict:
    """The state, or {} when there is none yet or it cannot be read (a torn or foreign file is not fatal)."""
    try:
        doc = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return {}
    return doc if isinstance(doc, dict) else {}


def save_state(path: Path, state: dict) -> None:
    atomic_write(Path(path), (json.dumps(state, indent=1, sort_keys=True) + "\n").encode())


def record(path: Path, report: dict, now: float | None = None) -> dict:
    """Merge one sync's report into the state: the last attempt, the last success, and running totals."""
    now = time.time() if now is None else now
    state = load_state(path)
    result = report["result"]
    counts = {k: int(v) for k, v in state.get("results_total", {}).items() if k in RESULTS}
    counts[result] = counts.get(result, 0) + 1
    outcomes = {k: int(v) for k, v in state.get("outcomes_total", {}).items() if k in OUTCOMES}
    for o in report.get("garments", []):
        outcomes[o["outcome"]] = outcomes.get(o["outcome"], 0) + 1
    state.update(results_total=counts, outcomes_total=outcomes, last_attempt=now, last_result=result,
                 last_detail=report.get("detail", ""), last_garments=report.get("garments", []))
    if report.get("metadata"):
        state["metadata"] = {k: v for k, v in report["metadata"].items() if k != "verified"}
        if report["metadata"].get("verified"):
            state["metadata_verified_at"] = now
    if result == "ok":
        state["last_success"] = now
        state["consecutive_failures"] = 0
    else:
        state["consecutive_failures"] = int(state.get("consecutive_failures", 0)) + 1
    save_state(path, state)
    return state


def _expiry_epoch(state: dict) -> float | None:
    text = state.get("metadata", {}).get("timestamp_expires")
    try:
        return datetime.fromisoformat(text.replace("Z", "+00:00")).timestamp() if text else None
    except (AttributeError, ValueError):
        return None


def section(path: Path, stale_after_s: float, now: float | None = None) -> dict:
    """The `fleet` object of /healthz."""
    now = time.time() if now is None else now
    state = load_state(path)
    verified = state.get("metadata_verified_at")
    age = now - verified if isinstance(verified, (int, float)) else None
    expires = _expiry_epoch(state)
    return {"metadata_age_s": None if age is None else round(age, 1),
            "stale": age is None or age > stale_after_s,
            "timestamp_expires_in_s": None if expires is None else round(expires - now, 1),
            "last_result": state.get("last_result"), "last_detail": state.get("last_detail"),
            "consecutive_failures": int(state.get("consecutive_failures", 0)),
            "timestamp_version": state.get("metadata", {}).get("timestamp_version")}


def _age_text(seconds: float) -> str:
    for unit, size in (("d", 86400), ("h", 3600), ("min", 60)):
        if seconds >= size:
            return f"{seconds / size:.1f} {unit}"
    return f"{seconds:.0f} s"


def fleet_check(path: Path, stale_after_s: float, clock: Callable[[], float] = time.time) -> Callable[[], CheckResult]:
    """The /healthz check (always ok, see the module doc): metadata age, and the last sync's trouble if any."""

    def check() -> CheckResult:
        s = section(path, stale_after_s, clock())
        if s["metadata_age_s"] is None:
            text = "no successful sync yet"
        else:
            text = f"metadata {_age_text(s['metadata_age_s'])} old" + (" (stale)" if s["stale"] else "")
        if s["last_result"] not in (None, "ok"):
            text += f"; last sync {s['last_result']} ({s['consecutive_failures']} in a row): {s['last_detail']}"
        return CheckResult(True, text + "; serving the installed bundles")

    return check


def register_metrics(registry, path: Path, clock: Callable[[], float] = time.time) -> None:
    """Gauges and counters read from the state file at each scrape (the sync job keeps the totals)."""

    def read(fn: Callable[[dict], float | None]) -> Callable[[], float]:
        def value() -> float:
            v = fn(load_state(path))
            return math.nan if v is None else float(v)
        return value

    registry.gauge("vtkiosk_fleet_metadata_age_seconds", "Seconds since the update metadata was last verified fresh."
                   ).set_function(read(lambda s: clock() - s["metadata_verified_at"] if "metadata_verified_at" in s
                                       else None))
    registry.gauge("vtkiosk_fleet_timestamp_expires_in_seconds", "Seconds until the trusted timestamp expires."
                   ).set_function(read(lambda s: (e - clock()) if (e := _expiry_epoch(s)) is not None else None))
    registry.gauge("vtkiosk_fleet_sync_consecutive_failures", "Syncs in a row that did not finish ok."
                   ).set_function(read(lambda s: s.get("consecutive_failures", 0)))
    runs = registry.counter("vtkiosk_fleet_syncs_total", "Fleet syncs by result.", labels=("result",))
    for r in RESULTS:
        runs.set_function(read(lambda s, r=r: s.get("results_total", {}).get(r, 0)), result=r)
    per = registry.counter("vtkiosk_fleet_bundle_outcomes_total", "Per-garment sync outcomes.", labels=("outcome",))
    for o in OUTCOMES:
        per.set_function(read(lambda s, o=o: s.get("outcomes_total", {}).get(o, 0)), outcome=o)
