"""The daemon works inside the unit's sandbox, not only on paper.

There is no systemd (PID 1) on a build machine, so the two settings that could break the daemon at run time are
reproduced with the kernel features systemd itself uses:
- MemoryDenyWriteExecute=yes: the kernel's MDWE (prctl PR_SET_MDWE, PR_MDWE_REFUSE_EXEC_GAIN; systemd >= 254
  uses it too, older systemd a seccomp filter with the same effect): no mapping may be writable and executable.
  ONNX Runtime's CPU kernels (MLAS, fp32 and int8 QDQ) must run without W+X pages.
- SystemCallFilter=@system-service ~@privileged with SystemCallErrorNumber=EPERM: a seccomp allow list built
  (with libseccomp, as systemd does) from systemd-analyze's own definition of those groups.
plus NoNewPrivileges. The real `vtkiosk serve` then starts, renders a frame on the emulated device, answers
/healthz and stops cleanly on SIGTERM.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import errno
import grp
import json
import os
import shutil
import subprocess
import sys
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from tests.kiosk.bundle_factory import make_bundle
from tests.kiosk.serve_process import ServeProcess

ROOT = Path(__file__).resolve().parents[2]
PR_SET_NO_NEW_PRIVS, PR_SET_MDWE, PR_MDWE_REFUSE_EXEC_GAIN = 38, 65, 1
SCMP_ACT_ALLOW = 0x7FFF0000


def _libc():
    return ctypes.CDLL(None, use_errno=True)


def mdwe_supported() -> bool:
    """Ask in a child, so this process keeps its own memory rules."""
    probe = f"import ctypes,sys; sys.exit(0 if ctypes.CDLL(None).prctl({PR_SET_MDWE}, 1, 0, 0, 0) == 0 else 1)"
    return subprocess.run([sys.executable, "-c", probe], timeout=30).returncode == 0


def syscall_groups() -> dict[str, list[str]]:
    out = subprocess.run([shutil.which("systemd-analyze"), "syscall-filter", "--no-pager"], capture_output=True,
                         text=True, timeout=60).stdout
    groups: dict[str, list[str]] = {}
    current = None
    for line in out.splitlines():
        if line.startswith("@"):
            current = line.strip()
            groups[current] = []
        elif line.startswith("    ") and current and not line.strip().startswith("#"):
            groups[current].append(line.strip())
    return groups


def expand(name: str, groups: dict[str, list[str]]) -> set[str]:
    out: set[str] = set()
    for item in groups[name]:
        out |= expand(item, groups) if item.startswith("@") else {item}
    return out


def unit_allow_list() -> list[str]:
    """The allow list that systemd/vtkiosk.service's SystemCallFilter= lines give (an allow list, then ~removals)."""
    from tests.systemd.test_units import UNITS, unit_settings

    g = syscall_groups()
    allowed: set[str] = set()
    for value in unit_settings(UNITS / "vtkiosk.service")["SystemCallFilter"]:
        deny = value.startswith("~")
        names = set().union(*(expand(n, g) if n.startswith("@") else {n} for n in value.lstrip("~").split()))
        allowed = allowed - names if deny else allowed | names
    return sorted(allowed)


def sandbox(allowed: list[str]):
    """A preexec_fn: NoNewPrivileges, MDWE, and the seccomp allow list (everything else fails with EPERM)."""
    lib = ctypes.CDLL(ctypes.util.find_library("seccomp") or "libseccomp.so.2", use_errno=True)
    lib.seccomp_init.restype = ctypes.c_void_p
    lib.seccomp_init.argtypes = [ctypes.c_uint32]
    lib.seccomp_syscall_resolve_name.argtypes = [ctypes.c_char_p]
    lib.seccomp_rule_add.argtypes = [ctypes.c_void_p, ctypes.c_uint32, ctypes.c_int, ctypes.c_uint]
    lib.seccomp_load.argtypes = [ctypes.c_void_p]
    names = [n.encode() for n in allowed]
    libc = _libc()

    def apply() -> None:
        if libc.prctl(PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0) != 0:
            raise OSError(ctypes.get_errno(), "PR_SET_NO_NEW_PRIVS")
        if libc.prctl(PR_SET_MDWE, PR_MDWE_REFUSE_EXEC_GAIN, 0, 0, 0) != 0:
            raise OSError(ctypes.get_errno(), "PR_SET_MDWE")
        ctx = lib.seccomp_init(0x00050000 | errno.EPERM)  # SCMP_ACT_ERRNO(EPERM)
        for n in names:
            nr = lib.seccomp_syscall_resolve_name(n)
            if nr >= 0:  # names this architecture does not have resolve to negative pseudo numbers
                lib.seccomp_rule_add(ctx, SCMP_ACT_ALLOW, nr, 0)
        if lib.seccomp_load(ctx) != 0:
            raise OSError("seccomp_load failed")

    return apply


needs = pytest.mark.skipif(shutil.which("systemd-analyze") is None or ctypes.util.find_library("seccomp") is None
                           or not mdwe_supported(),
                           reason="needs systemd-analyze, libseccomp and a kernel with PR_SET_MDWE (Linux >= 6.3)")


@pytest.fixture(scope="module")
def allowed():
    names = unit_allow_list()
    assert {"read", "execve", "mmap", "socket"} <= set(names) and "chown" not in names and "reboot" not in names
    return names


SELF_CHECK = """
import mmap, os, sys
try:
    mmap.mmap(-1, 4096, prot=mmap.PROT_READ | mmap.PROT_WRITE | mmap.PROT_EXEC)
    print("wx-allowed")
except PermissionError:
    print("wx-refused")
try:
    os.chown(sys.argv[1], -1, os.getgid())
    print("chown-allowed")
except PermissionError:
    print("chown-refused")
"""


@needs
def test_the_sandbox_is_real(tmp_path, allowed):
    f = tmp_path / "f"
    f.write_text("x")
    plain = subprocess.run([sys.executable, "-c", SELF_CHECK, str(f)], capture_output=True, text=True, timeout=60)
    boxed = subprocess.run([sys.executable, "-c", SELF_CHECK, str(f)], capture_output=True, text=True, timeout=60,
                           preexec_fn=sandbox(allowed))
    assert plain.stdout.split() == ["wx-allowed", "chown-allowed"]
    assert boxed.stdout.split() == ["wx-refused", "chown-refused"], boxed.stderr


ORT_RUN = """
import sys, numpy as np, onnxruntime as ort
from kiosk.bundle.probe import session_options
for path in sys.argv[1:]:
    s = ort.InferenceSession(path, session_options(2), providers=["CPUExecutionProvider"])
    x = np.random.default_rng(0).standard_normal((1, 3, 128, 128)).astype(np.float32)
    y = s.run(None, {"x": x})[0]
    assert np.isfinite(y).all() and y.shape == (1, 8, 128, 128)
    print(path.rsplit("/", 1)[1], float(np.abs(y).mean()))
"""


def conv_models(tmp_path: Path) -> list[Path]:
    """A small conv stack in fp32, and its int8 QDQ quantization (the exporter's quantizer settings)."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper
    from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static

    rng = np.random.default_rng(1)
    w1 = numpy_helper.from_array(rng.standard_normal((16, 3, 3, 3)).astype(np.float32) * 0.2, "w1")
    w2 = numpy_helper.from_array(rng.standard_normal((8, 16, 3, 3)).astype(np.float32) * 0.2, "w2")
    nodes = [helper.make_node("Conv", ["x", "w1"], ["h"], pads=[1, 1, 1, 1]),
             helper.make_node("Relu", ["h"], ["r"]),
             helper.make_node("Conv", ["r", "w2"], ["y"], pads=[1, 1, 1, 1])]
    graph = helper.make_graph(nodes, "convs", [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 3, 128, 128])],
                              [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 8, 128, 128])], [w1, w2])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    fp32, int8 = tmp_path / "fp32.onnx", tmp_path / "int8.onnx"
    onnx.save(model, str(fp32))

    class Reader(CalibrationDataReader):
        def __init__(self):
            self.items = iter([{"x": rng.standard_normal((1, 3, 128, 128)).astype(np.float32)} for _ in range(4)])

        def get_next(self):
            return next(self.items, None)

    quantize_static(str(fp32), str(int8), Reader(), quant_format=QuantFormat.QDQ, activation_type=QuantType.QUInt8,
                    weight_type=QuantType.QInt8)
    return [fp32, int8]


@needs
def test_onnx_runtime_fp32_and_int8_need_no_wx_memory_nor_privileged_syscalls(tmp_path, allowed):
    models = conv_models(tmp_path)
    proc = subprocess.run([sys.executable, "-c", ORT_RUN, *map(str, models)], cwd=ROOT, capture_output=True,
                          text=True, timeout=120, preexec_fn=sandbox(allowed))
    assert proc.returncode == 0, proc.stderr
    assert [line.split()[0] for line in proc.stdout.splitlines()] == ["fp32.onnx", "int8.onnx"]


@needs
@pytest.mark.slow
def test_the_daemon_serves_inside_the_units_sandbox(tmp_path, allowed):
    bundle, trusted = make_bundle(tmp_path)
    run = tmp_path / "run"
    run.mkdir()
    gid = os.getgid()
    os.chown(run, -1, gid)
    run.chmod(0o2750)  # like RuntimeDirectoryMode=2750 after ExecStartPre=+chgrp: the socket inherits the group
    config = {"server": {"port": 0}, "bundles": [str(bundle)], "store": {"trusted_keys": str(trusted)},
              "device": {"type": "emulated", "report_size": 1024},
              "control": {"socket": str(run / "control.sock"), "group": grp.getgrgid(gid).gr_name},
              "state_dir": str(tmp_path / "state")}
    kiosk = ServeProcess(config, tmp_path, preexec_fn=sandbox(allowed))
    with kiosk:
        body = {"garment": "denim-shorts", "panel": {"x": 0, "y": 0, "w": 1280, "h": 800}, "screen": [1280, 800],
                "strokes": [[[300, 200], [800, 200], [800, 600], [300, 600], [300, 200]]], "base": False,
                "mode": "final", "client": "sandbox"}
        req = urllib.request.Request(kiosk.url + "api/render", data=json.dumps(body).encode(),
                                     headers={"Content-Type": "application/json"})
        with urllib.request.urlopen(req, timeout=60) as r:
            assert r.status == 200 and len(r.read()) > 1000
        with urllib.request.urlopen(kiosk.url + "healthz", timeout=30) as r:
            assert json.loads(r.read())["ok"] is True
        sock = run / "control.sock"
        assert sock.stat().st_gid == gid and (sock.stat().st_mode & 0o777) == 0o660
    assert kiosk.proc.returncode == 0, "".join(kiosk.output)
    assert "Operation not permitted" not in "".join(kiosk.output)
