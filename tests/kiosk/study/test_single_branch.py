"""A haptic trial against a single-branch bundle (the paper's baselines export only the full graph) renders: the
study runs that graph for the friction map instead of refusing the trial."""
from __future__ import annotations

import pytest
import yaml

from kiosk.study.config import load_study_config
from kiosk.study.log import read_log
from kiosk.study.runtime import StudyRuntime

from .driver import StudyPage, operator
from .helpers import study_doc
from .study_bundles import make_study_bundles

pytestmark = pytest.mark.slow


def test_trials_against_a_single_branch_bundle_render(tmp_path):
    garments = ["g00", "g01"]
    trusted = make_study_bundles(tmp_path, ["ours", "pix2pix"], garments, single_branch=("pix2pix",))
    doc = study_doc(garments=garments, warmup_garment="g00", test_garments=1, trusted_keys=str(trusted),
                    allow_unsigned=False, conditions={c: str(tmp_path / "bundles" / c / "{garment}.vtb")
                                                      for c in ("ours", "pix2pix")},
                    kiosk={"server": {"port": 0}, "inference": {"latency_budget_ms": 5000}}, release="none",
                    timeout_notice_s=0)
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    cfg = load_study_config(tmp_path / "s.yaml")
    rt = StudyRuntime(cfg, port=0, device="emulated", control_socket=tmp_path / "s.sock")
    page = StudyPage(rt.daemon.server.url)
    try:
        operator(tmp_path / "s.sock", "study.start", participant="P01")
        while (st := page.state())["state"] != "done":
            assert st["state"] == "trial", (st, operator(tmp_path / "s.sock", "study.status"))
            tr = st["trial"]
            page.shown(tr["token"])
            assert page.choose(tr["token"], "left")["recorded"]
    finally:
        rt.close()
    answered = [r for r in read_log(cfg.log).records if r["type"] == "response"]
    assert len(answered) == 2 and all(r["choice"] == "left" for r in answered)
