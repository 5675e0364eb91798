"""The edge runtime (kiosk/, firmware_bridge/) must import and work on a machine without torch."""
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

BLOCK_TORCH = textwrap.dedent("""
    import importlib.abc, sys
    class _NoTorch(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name == "torch" or name.startswith("torch."):
                raise ImportError("torch is not installed on this kiosk (blocked by the test)")
            return None
    sys.meta_path.insert(0, _NoTorch())
""")


def _run(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", BLOCK_TORCH + textwrap.dedent(code)], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)


def test_blocker_really_blocks_torch():
    proc = _run("import torch")
    assert proc.returncode != 0 and "blocked by the test" in proc.stderr


def test_runtime_packages_import_without_torch():
    proc = _run("""
        import pkgutil, importlib, sys
        import kiosk, firmware_bridge
        names = []
        for pkg in (kiosk, firmware_bridge):
            for info in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + "."):
                importlib.import_module(info.name)
                names.append(info.name)
        assert "torch" not in sys.modules
        print(len(names), "modules")
    """)
    assert proc.returncode == 0, proc.stderr
    assert "modules" in proc.stdout


def test_contract_runs_without_torch():
    proc = _run("""
        import numpy as np
        from kiosk.contract.sketch import rasterize, object_mask, network_input
        from kiosk.contract.haptics import friction_map
        s = rasterize([[(10, 10), (50, 10), (50, 40), (10, 40), (10, 10)]], (64, 48))
        x = network_input(s, object_mask(s))
        f = friction_map(np.ones((48, 64)), np.zeros((48, 64)), 0.1, size=(32, 24))
        print(x.sketch.shape, f.shape)
    """)
    assert proc.returncode == 0, proc.stderr
    assert "(1, 1, 48, 64) (24, 32)" in proc.stdout
