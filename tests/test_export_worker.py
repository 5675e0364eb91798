"""The demo's warm export workers (vtkiosk/export_worker.py): bad job lines and failing jobs get one clear reply
each and the worker stays up; a failed catalogue export names its garment and leaves no worker behind."""
import json
import os
import subprocess
import sys
from pathlib import Path

from vtkiosk import demo
from vtkiosk.catalogue import CATALOGUE, load_index

ROOT = Path(__file__).resolve().parents[1]


def _children_running(module: str) -> list[int]:
    me = str(os.getpid())
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            ppid = stat.read_text().rsplit(")", 1)[1].split()[1]
            cmd = (stat.parent / "cmdline").read_bytes().decode(errors="replace")
        except (OSError, IndexError):
            continue
        if ppid == me and module in cmd:
            found.append(int(stat.parent.name))
    return found


def test_worker_answers_every_line_and_survives_failing_jobs(tmp_path):
    entry = load_index(CATALOGUE)[0]

    def job(i, **kw):
        j = {"id": i, "entry": entry.id, "data_dir": str(tmp_path / "data"), "run_dir": str(tmp_path / f"run{i}"),
             "argv": ["--run", str(tmp_path / f"run{i}"), "--out", str(tmp_path / "x.vtb"), "--precision", "int9"],
             "log": str(tmp_path / f"job{i}.log")}
        j.update(kw)
        return json.dumps(j)

    lines = ["not json", json.dumps([1, 2]), json.dumps({"id": 7}), job(1, argv="--run x"),
             job(2, entry="no-such-garment"), job(3)]
    proc = subprocess.run([sys.executable, "-m", "vtkiosk.export_worker"], input="\n".join(lines) + "\n",
                          cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    replies = [json.loads(line) for line in proc.stdout.splitlines()]
    assert replies[0] == {"ready": True}
    bad = replies[1:5]
    assert [r["id"] for r in bad] == [None] * 4 and not any(r["ok"] for r in bad)
    assert "bad job line" in bad[0]["error"] and "JSON object" in bad[1]["error"]
    assert "needs entry, data_dir" in bad[2]["error"] and "argv must be a list" in bad[3]["error"]
    assert replies[5] == {"id": 2, "ok": False, "error": "ValueError: no catalogue entry 'no-such-garment'"}
    # a real garment whose export refuses its arguments: the data and run were made, the refusal is in the log
    assert replies[6]["id"] == 3 and not replies[6]["ok"] and "exited 2" in replies[6]["error"]
    assert (tmp_path / "run3" / "checkpoints" / "best.pt").is_file()
    assert "invalid choice: 'int9'" in (tmp_path / "job3.log").read_text()
    assert len(replies) == 7


SCRIPT = """
import os, sys
from pathlib import Path
from vtkiosk import demo
from tests.test_export_worker import _children_running
demo.CATALOGUE_MAX_FRICTION_MAE = "lots"   # the exporter refuses it, after the data step
try:
    demo.build_catalogue(Path(sys.argv[1]))
except demo.DemoError as e:
    print("ERROR", str(e).splitlines()[0])
print("workers left", _children_running("vtkiosk.export_worker"))
print("torch loaded", "torch" in sys.modules)
"""


def test_a_failed_catalogue_export_names_the_garment_and_stops_the_workers(tmp_path):
    proc = subprocess.run([sys.executable, "-c", SCRIPT, str(tmp_path / "w")], cwd=ROOT, capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    out = [line for line in proc.stdout.splitlines() if not line.startswith("demo: ")]
    assert out[0].startswith("ERROR exporting ") and "(RuntimeError: vtkiosk export exited 2)" in out[0], out
    assert out[1:] == ["workers left []", "torch loaded False"]   # the serving process never imports torch
    assert not any((tmp_path / "w" / "catalogue").glob("*/*.vtb"))
