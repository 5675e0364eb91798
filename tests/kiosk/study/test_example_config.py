"""configs/study.example.yaml runs as written: `ours` against pix2pix, pix2pixhd and gaugan, with consent, the
optional questions, familiarisation and the operator's release between trials, against bundles that the trainer
and the exporter made from the synthetic set (each method's real generator, for each of the six garments the example
names), through a real `vtkiosk study run` process: the page over HTTP on loopback, the operator through
`vtkiosk study start` and `vtkiosk study next`.

Only what the example documents as site-specific is replaced: the `log` and `trusted_keys` paths and the operator
socket (`kiosk.control.socket`; its system `group` is dropped, a group the package's sysusers file creates). The
port and the device are the `study run` command's own overrides (`--port 0`, `--device emulated`).
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from kiosk.contract.garment import garment_id
from kiosk.study.config import load_study_config
from kiosk.study.log import read_log
from kiosk.study.report import report_log
from kiosk.study.schedule import make_schedule
from tests.tiny_models import keypair, synthetic_set, tiny_bundle, tiny_run

from .simulate import ROOT, StudyProcess

pytestmark = pytest.mark.slow

EXAMPLES = ROOT / "configs"
CLI_TIMEOUT_S = 60
READY_TIMEOUT_S = 600     # verifying and probing 24 bundles; minutes when the machine is shared


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """A folder laid out as the example expects (bundles/<condition>/<garment>.vtb beside the config); returns the
    config written there with only the site-specific paths replaced."""
    root = tmp_path_factory.mktemp("example-study")
    doc = yaml.safe_load((EXAMPLES / "study.example.yaml").read_text())
    folders = {garment_id(p.name): p for p in synthetic_set(root / "data", 6)}
    assert set(doc["garments"]) <= set(folders), "the example names garments the synthetic set does not have"
    signing_key, trusted = keypair(root)
    for condition, template in doc["conditions"].items():
        for garment in doc["garments"]:
            run = tiny_run(folders[garment], condition, root / "runs" / condition / garment, steps=0)
            tiny_bundle(run, root / template.format(garment=garment), signing_key)
    doc["log"] = str(root / "study.jsonl")
    doc["trusted_keys"] = str(trusted)
    doc["kiosk"]["control"] = {"socket": str(root / "study.sock")}
    out = root / "study.yaml"
    out.write_text(yaml.safe_dump(doc, sort_keys=False))
    return out


def vtk_study(*args: str) -> str:
    proc = subprocess.run([sys.executable, "-m", "vtkiosk", "study", *args], capture_output=True, text=True,
                          cwd=ROOT, timeout=CLI_TIMEOUT_S)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout


def test_the_haptic_example_config_runs_a_full_session_on_trained_bundles(site, tmp_path):
    cfg = load_study_config(site)
    assert cfg.comparisons == ("pix2pix", "pix2pixhd", "gaugan") and cfg.release == "each_trial"
    proc = StudyProcess(site, tmp_path / "proc", ready_timeout_s=READY_TIMEOUT_S)
    proc.start()
    page = proc.page
    try:
        vtk_study("start", "--config", str(site), "--participant", "P01")
        st = page.state()
        page.raw("POST", "/api/study/consent", {"token": st["token"], "agreed": True, "version": "2026-01"})
        st = page.state()
        page.raw("POST", "/api/study/demographics", {"token": st["token"], "answers": {"age_band": "25-34",
                                                                                      "dominant_hand": "right"}})
        for step in range(len(cfg.familiarisation.textures)):
            st = page.state()
            assert st["state"] == "familiarisation" and st["step"] == step + 1
            page.raw("POST", "/api/study/familiarised", {"token": st["token"]})
        schedule = make_schedule(cfg, "P01")
        for t in schedule.trials:
            assert page.state()["state"] == "wait"                      # the inter-trial pause
            status = vtk_study("status", "--config", str(site))
            assert t.garment in status, status                         # the operator sees the garment for the table
            vtk_study("next", "--config", str(site))
            st = page.state()
            assert st["state"] == "trial", (st, vtk_study("status", "--config", str(site)))
            tr = st["trial"]
            page.raw("POST", "/api/study/shown", {"token": tr["token"], "page": "p"})
            assert page.choose(tr["token"], t.side_of("ours"))["recorded"]
        assert page.state()["state"] == "done"
    finally:
        assert proc.stop() == 0
    records = read_log(cfg.log).records
    assert len([r for r in records if r["type"] == "release"]) == len(schedule.trials) == 1 + 5 * 3
    served = {(c, g): ident["method"] for r in records if r["type"] == "session"
              for c, per in r["bundles"].items() for g, ident in per.items()}
    assert served == {(c, g): c for c in ("ours", "pix2pix", "pix2pixhd", "gaugan") for g in cfg.garments}
    rep = report_log(cfg.log, resamples=200)
    assert [c["baseline"] for c in rep["comparisons"]] == ["gaugan", "pix2pix", "pix2pixhd"]
    assert all(c["rate"] == 1.0 for c in rep["comparisons"])             # P01 chose ours every time
    assert rep["demographics"]["line"] == "1 participant; age band: 25-34 1; dominant hand: right 1"


def test_the_visual_example_config_loads():
    cfg = load_study_config(EXAMPLES / "study-visual.example.yaml")
    assert cfg.kind == "visual" and cfg.warmup_trials == 5
    assert cfg.test_garments * len(cfg.comparisons) == 30                 # the paper's 30 test rounds
