"""`vtkiosk device ...` and the typed config; import hygiene (no torch, nothing else of ours)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from firmware_bridge.cli import main
from firmware_bridge.config import BridgeConfig, EmulatorConfig, FaultConfig
from firmware_bridge.errors import BridgeError, ConfigError, NoDeviceError

ROOT = Path(__file__).resolve().parents[2]


def test_probe_without_hardware_is_one_clean_line_and_non_zero():
    proc = subprocess.run([str(ROOT / ".venv/bin/vtkiosk"), "device", "probe"], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode != 0
    assert proc.stderr.strip().splitlines() == [
        "vtkiosk device: error: no bridge found (looked for VID:PID 1209:0001 over hid, usb)"]


def test_probe_lists_an_emulated_bridge(capsys):
    assert main(["probe", "--type", "emulated"], prog="vtkiosk device") == 0
    out = capsys.readouterr().out
    assert "found: emulated 1209:0001" in out and "panel 1280x800" in out and "tile 64x64" in out


def test_probe_errors_are_user_facing():
    with pytest.raises(NoDeviceError) as exc:
        main(["probe", "--type", "hid", "--vid", "0x1234", "--pid", "0x5678"], prog="vtkiosk device")
    assert exc.value.user_facing and "1234:5678" in str(exc.value)
    assert issubclass(ConfigError, BridgeError) and BridgeError.user_facing is True


def test_bench_writes_json_and_meets_goals(tmp_path, capsys):
    out = tmp_path / "bridge.json"
    assert main(["bench", "--edits", "3", "--json", str(out)], prog="vtkiosk device") == 0
    text = capsys.readouterr().out
    assert "| hs-hid | full frame | delta+zlib |" in text and "link time (modelled)" in text
    data = json.loads(out.read_text())
    assert {r["mode"] for r in data["rows"]} == {"raw", "delta", "delta+zlib"}
    assert data["goals"]["stroke_edit_fraction_of_raw"]["met"]
    assert data["goals"]["full_frame_hs_hid_link_s"]["met"]
    assert any(c["codec"] == "zlib-1" for c in data["compression"])


def test_config_from_mapping_with_hex_ids_and_nested_emulator(tmp_path):
    cfg = BridgeConfig.from_mapping({"type": "usb", "vid": "0x1209", "pid": 1, "report_size": 1024,
                                     "ack_timeout_s": 1, "emulator": {"panel_w": 640, "faults": {"drop": 0.1}}})
    assert cfg.vid == 0x1209 and cfg.ack_timeout_s == 1.0 and cfg.emulator.panel_w == 640
    assert cfg.emulator.faults.drop == 0.1
    path = tmp_path / "kiosk.yaml"
    path.write_text("bridge:\n  type: hid\n  serial: ABC\n  window: 8\n")
    assert BridgeConfig.from_yaml(path, key="bridge") == BridgeConfig(type="hid", serial="ABC", window=8)


@pytest.mark.parametrize("data, match", [
    ({"typo": 1}, r"unknown key\(s\): typo"),
    ({"type": "serial"}, "type must be one of"),
    ({"vid": 0x10000}, "16-bit"),
    ({"vid": "zz"}, "hex string"),
    ({"window": "8"}, "window must be an integer"),
    ({"max_retries": True}, "max_retries must be an integer"),
    ({"compression": "lz4"}, "compression"),
    ({"emulator": {"faults": {"drop": 2}}}, r"faults.drop is a probability"),
    ({"emulator": {"firmware": "1.2"}}, "firmware"),
    ({"emulator": {"bogus": 1}}, r"unknown key\(s\) in emulator: bogus"),
])
def test_config_errors_name_the_key(data, match):
    with pytest.raises(ConfigError, match=match):
        BridgeConfig.from_mapping(data)


def test_fault_and_emulator_defaults_are_quiet():
    assert not FaultConfig().any and EmulatorConfig().faults == FaultConfig()


def test_package_imports_nothing_of_ours_no_torch_and_works_without_hidapi_or_pyusb():
    code = (
        "import sys\n"
        "sys.modules.update({'hid': None, 'usb': None, 'usb.core': None, 'usb.util': None})  # absent\n"
        "import pkgutil, importlib, firmware_bridge\n"
        "for m in pkgutil.walk_packages(firmware_bridge.__path__, 'firmware_bridge.'):\n"
        "    importlib.import_module(m.name)\n"
        "bad = sorted(n for n in sys.modules if n.split('.')[0] in "
        "('torch', 'kiosk', 'trainer', 'exporter', 'vtkiosk'))\n"
        "lazy = sorted(n for n, m in sys.modules.items() if m is not None and n.split('.')[0] in ('hid', 'usb'))\n"
        "print(bad, lazy)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[] []", out.stdout
