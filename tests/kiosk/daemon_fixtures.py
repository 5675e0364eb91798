"""Helpers for tests that run a real kiosk daemon: real bundles (tests/kiosk/bundle_factory.py), the in-process
emulated haptic device, real HTTP on 127.0.0.1."""
from __future__ import annotations

import json
import time
import urllib.error
import urllib.request
from pathlib import Path

from kiosk.service.config import config_from_mapping
from kiosk.service.daemon import KioskDaemon
from kiosk.service.frames import parse_frame

BOX = [[[300, 200], [800, 200], [800, 600], [300, 600], [300, 200]]]


def daemon_config(bundles: list[Path], trusted: Path, **sections):
    doc = {"server": {"port": 0}, "bundles": [str(b) for b in bundles], "store": {"trusted_keys": str(trusted)},
           "device": {"type": "emulated", "report_size": 1024, "heartbeat_interval_s": 0.05,
                      "reconnect_interval_s": 0.05},
           "health": {"stale_after_s": 1.0, "interval_s": 0.1}, "debug": {"fault_injection": True}}
    for k, v in sections.items():
        doc[k] = {**doc.get(k, {}), **v} if isinstance(v, dict) else v
    return config_from_mapping(doc)


def start_daemon(bundles: list[Path], trusted: Path, **sections) -> KioskDaemon:
    d = KioskDaemon(daemon_config(bundles, trusted, **sections))
    d.start()
    return d


def http(url: str, body: object | None = None, *, raw: bytes | None = None, timeout: float = 30.0,
         headers: dict | None = None) -> tuple[int, bytes, str]:
    data = raw if raw is not None else (json.dumps(body).encode() if body is not None else None)
    req = urllib.request.Request(url, data=data, headers={"Content-Type": "application/json", **(headers or {})})
    try:
        with urllib.request.urlopen(req, timeout=timeout) as r:
            return r.status, r.read(), r.headers.get("Content-Type", "")
    except urllib.error.HTTPError as e:
        return e.code, e.read(), e.headers.get("Content-Type", "")


def render(d: KioskDaemon, strokes=BOX, *, garment="denim-shorts", mode="final", panel=(0, 0, 1280, 800),
           base=False, client="test"):
    body = {"garment": garment, "panel": dict(zip("xywh", panel)), "screen": [1280, 800], "strokes": strokes,
            "base": base, "mode": mode, "client": client}
    status, data, ctype = http(d.server.url + "api/render", body)
    if status != 200 or ctype.startswith("application/json"):  # an error, or {"superseded": true}
        return status, json.loads(data), {}
    return status, *parse_frame(data)


def settle(d: KioskDaemon, strokes=BOX, **kw):
    """A stroke end as the page answers it: the quick answer, then the refinement it asks for (which brings the
    friction when the quick answer left it out, `inference.quick_tactile`). Returns the last answer."""
    out = render(d, strokes, **kw)
    if out[0] == 200 and out[1].get("refine"):
        out = render(d, strokes, **{**kw, "mode": "refine"})
    return out


def wait_for(cond, timeout: float = 5.0, step: float = 0.02) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(step)
    return cond()


def demo_build(tmp_path_factory, steps: int = 2) -> tuple[Path, Path, str]:
    """Build (once per test session: `vtkiosk demo` caches it) a real demo bundle with our trainer and exporter,
    on a short schedule. Returns (bundle, trusted-keys folder, the command's output). VTKIOSK_TEST_DEMO_DIR keeps
    the build across sessions (for iterating on the page tests)."""
    import os
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[2]
    workdir = Path(os.environ.get("VTKIOSK_TEST_DEMO_DIR") or tmp_path_factory.getbasetemp() / "demo-build")
    proc = subprocess.run([sys.executable, "-m", "vtkiosk", "demo", "--quick", "--workdir", str(workdir), "--steps", str(steps),
                           "--build-only"], cwd=root, capture_output=True, text=True, timeout=1200)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    (bundle,) = sorted((workdir / "bundles").glob("*/demo.vtb"))
    return bundle, workdir / "trusted-keys", proc.stdout


def demo_and_coat_daemon(tmp_path_factory, label: str) -> KioskDaemon:
    """A daemon serving two garments, so the page has a catalogue to switch: the trained demo bundle and a
    factory-made "Test coat", each signed by its own key and both keys trusted."""
    import shutil

    from tests.kiosk.bundle_factory import base_manifest, make_bundle

    bundle, trusted, _ = demo_build(tmp_path_factory)
    tmp = tmp_path_factory.mktemp(label)
    other, other_trusted = make_bundle(tmp, manifest=base_manifest(garment_id="test-coat", display_name="Test coat"))
    keys = tmp / "all-trusted"
    keys.mkdir()
    for folder in (trusted, other_trusted):
        for pub in folder.glob("*.pub"):
            shutil.copy(pub, keys / f"{folder.parent.name}-{pub.name}")
    return start_daemon([bundle, other], keys)

