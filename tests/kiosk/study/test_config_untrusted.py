"""A study config from a hostile or careless hand: deep nesting and huge numbers are one-line errors (rc 2)."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from kiosk.study.config import StudyConfigError, load_study_config

ROOT = Path(__file__).resolve().parents[3]
BAD = {"deep": "[" * 2000 + "]" * 2000, "deep-block": "".join(" " * i + "-\n" for i in range(700)) + " " * 700 + "1",
       "huge-int": "id: x\nseed: " + "9" * 5000 + "\n"}


@pytest.mark.parametrize("kind", sorted(BAD))
def test_hostile_yaml_is_a_one_line_study_config_error(tmp_path, kind):
    path = tmp_path / "study.yaml"
    path.write_text(BAD[kind])
    with pytest.raises(StudyConfigError) as e:
        load_study_config(path)
    assert "\n" not in str(e.value) and len(str(e.value)) < 400


def test_the_study_kiosk_config_is_read_the_same_way(tmp_path):
    from kiosk.study.runtime import control_socket_of

    from .helpers import study_config

    (tmp_path / "kiosk.yaml").write_text(BAD["deep"])
    cfg = study_config(tmp_path, kiosk=str(tmp_path / "kiosk.yaml"))
    with pytest.raises(StudyConfigError, match="not valid YAML"):
        control_socket_of(cfg)


def test_the_command_exits_2_with_one_line(tmp_path):
    path = tmp_path / "study.yaml"
    path.write_text(BAD["deep"])
    proc = subprocess.run([sys.executable, "-m", "vtkiosk", "study", "status", "--config", str(path)], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr, proc.stderr
