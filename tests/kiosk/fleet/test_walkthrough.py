"""docs/fleet.md runs as written: every `bash` block, in order, in one shell (`set -euo pipefail`), in an empty
folder that holds only what the walkthrough says you start with (two exported bundles and the bundle key's public
half). The lab's `python3 -m http.server` serves the repository on a free loopback port; the whole process group is
ended when the test ends, whatever happened."""
from __future__ import annotations

import os
import re
import shutil
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from kiosk.bundle.store import BundleStore
from tests.kiosk.bundle_factory import base_manifest, make_bundle

ROOT = Path(__file__).resolve().parents[3]
DOC = ROOT / "docs" / "fleet.md"
BLOCK = re.compile(r"^```bash\n(.*?)^```$", re.S | re.M)
OLD, NEW = "2026.11.21-1", "2026.11.28-1"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_the_doc_has_the_whole_walkthrough():
    script = "\n".join(BLOCK.findall(DOC.read_text()))
    for step in ("fleet init", "http.server", "fleet publish", "fleet sync", "fleet promote", "--rollout 10",
                 "fleet withdraw", "fleet refresh", "fleet rotate-key", "fleet status"):
        assert step in script, step


@pytest.mark.slow
def test_walkthrough_runs_as_written(tmp_path):
    src, work = tmp_path / "export", tmp_path / "work"
    (work / "bundles").mkdir(parents=True)
    (work / "bundle-keys").mkdir()
    for version in (OLD, NEW):
        bundle, trusted = make_bundle(src, name=f"denim-shorts-{version}.vtb",
                                      manifest=base_manifest(model_version=version))
        shutil.copy(bundle, work / "bundles" / bundle.name)
    shutil.copy(trusted / "operator.pub", work / "bundle-keys" / "operator.pub")
    script = "\n".join(BLOCK.findall(DOC.read_text()))
    env = {**os.environ, "PORT": str(_free_port()), "PYTHONPATH": str(ROOT),
           "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    proc = subprocess.Popen(["bash", "-euo", "pipefail", "-c", script], cwd=work, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        out, _ = proc.communicate(timeout=420)
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)  # the lab web server, if a step failed before `kill`
        except ProcessLookupError:
            pass
        proc.wait()
    assert proc.returncode == 0, out[-6000:]
    # What the walkthrough says happens, happened.
    assert "denim-shorts: installed" in out and "denim-shorts: withdrawn_rollback" in out, out[-6000:]
    assert "rotated the timestamp key" in out and "re-signed: " in out
    for kiosk in ("kiosk-a", "kiosk-b"):
        store = BundleStore(work / kiosk / "bundles", work / "bundle-keys")
        assert store.active()["denim-shorts"].version == OLD, kiosk
        assert sorted(s.version for s in store.list()) == [OLD, NEW], kiosk
    assert not list(work.glob("fleet-repo/**/*.key")), "a key ended up in the served folder"
