"""`vtkiosk study export --log LOG --out trials.csv`: one row per scheduled trial, PsychoPy-style wide CSV.

Like PsychoPy's trial-by-trial data file, every row repeats the session columns (`participant`, `session`, `date`,
`expName`) and carries the trial's variables and the response (`key_resp.keys`, `key_resp.rt`), so the file loads
straight into R or pandas. Every trial of every started session appears: answered, timed out, or still pending
(a session interrupted and not yet resumed), so nothing in the schedule is hidden. Several kiosks' logs of one
study are pooled first (`kiosk.study.merge`); the `kiosk` column says where each trial ran. A withdrawn
participant's rows stay in the file, marked `withdrawn` = 1, so an analysis can leave them out.
"""
from __future__ import annotations

import csv
from pathlib import Path

from kiosk.study.log import LogState
from kiosk.study.merge import merge_logs

COLUMNS = [
    "participant", "session", "date", "expName", "software", "trials.thisN", "block", "garment", "half",
    "reference", "comparison", "left_condition", "right_condition", "reference_side", "status", "key_resp.keys",
    "key_resp.rt", "chosen_condition", "chose_reference", "timed_out", "time_limit_s", "left_model_version",
    "left_manifest_sha256", "right_model_version", "right_manifest_sha256", "shown_wall", "response_wall",
    "response_mono", "boot_id", "log_seq", "kind", "kiosk", "withdrawn",
]


def _bit(v: object) -> str:
    return "" if v is None else str(int(bool(v)))


def rows(state: LogState) -> list[dict[str, object]]:
    out = []
    for (participant, session), s in sorted(state.sessions.items()):
        start = s.started
        bundles = start.get("bundles", {})
        for t in start["schedule"]["trials"]:
            r = s.responses.get(t["index"])
            ref = start["schedule"]["reference"]
            row: dict[str, object] = {
                "participant": participant, "session": session, "date": start.get("wall", ""),
                "expName": state.study_id, "software": start.get("software", ""), "trials.thisN": t["index"],
                "block": t["block"], "garment": t["garment"], "half": t["half"], "reference": ref,
                "comparison": t["comparison"], "left_condition": t["left"], "right_condition": t["right"],
                "reference_side": "left" if t["left"] == ref else "right",
                "left_model_version": bundles.get(t["left"], {}).get(t["garment"], {}).get("model_version", ""),
                "left_manifest_sha256": bundles.get(t["left"], {}).get(t["garment"], {}).get("manifest_sha256", ""),
                "right_model_version": bundles.get(t["right"], {}).get(t["garment"], {}).get("model_version", ""),
                "right_manifest_sha256": bundles.get(t["right"], {}).get(t["garment"], {}).get("manifest_sha256", ""),
                "kind": start.get("kind", "haptic"), "kiosk": start.get("kiosk", ""),
                "withdrawn": int(participant in state.withdrawn),
            }
            if r is None:
                row["status"] = "pending"
            else:
                row.update({
                    "status": "timeout" if r["timeout"] else "answered", "key_resp.keys": r["choice"] or "",
                    "key_resp.rt": "" if r["rt_s"] is None else f"{r['rt_s']:.4f}",
                    "chosen_condition": r["chosen"] or "", "chose_reference": _bit(r["chose_reference"]),
                    "timed_out": _bit(r["timeout"]),
                    "time_limit_s": "" if r["time_limit_s"] is None else r["time_limit_s"],
                    "shown_wall": r["shown_wall"], "response_wall": r["wall"], "response_mono": f"{r['mono']:.6f}",
                    "boot_id": r["boot_id"], "log_seq": r["seq"],
                })
            out.append(row)
    return out


def export_csv(log: Path | list[Path], out: Path) -> int:
    """Write the CSV of one log or of several kiosks' logs pooled; return the number of rows."""
    state = merge_logs(list(log) if isinstance(log, (list, tuple)) else [log]).state
    table = rows(state)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    with open(tmp, "w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS, restval="")
        writer.writeheader()
        writer.writerows(table)
    tmp.replace(out)
    return len(table)
