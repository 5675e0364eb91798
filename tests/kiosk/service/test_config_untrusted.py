"""The kiosk config from a hostile or careless hand: deep nesting, huge numbers, a bad port hidden by --port."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from kiosk.service.config import ConfigError, load_config

ROOT = Path(__file__).resolve().parents[3]
BAD = {"deep": "[" * 2000 + "]" * 2000, "deep-map": "server: " + "{a: " * 2000 + "1" + "}" * 2000,
       "huge-int": "server:\n  port: " + "9" * 5000 + "\n"}


@pytest.mark.parametrize("kind", sorted(BAD))
def test_hostile_yaml_is_a_one_line_config_error(tmp_path, kind):
    path = tmp_path / "kiosk.yaml"
    path.write_text(BAD[kind])
    with pytest.raises(ConfigError) as e:
        load_config(path)
    assert "\n" not in str(e.value) and len(str(e.value)) < 400 and str(path) in str(e.value)


def test_the_file_is_validated_on_its_own_even_when_an_option_overrides_it(tmp_path):
    path = tmp_path / "kiosk.yaml"
    path.write_text("bundles: [garment.vtb]\nserver:\n  port: 70000\n")
    for overrides in ({"server": {"port": 0}}, {}):
        with pytest.raises(ConfigError, match="server.port must be from 0"):
            load_config(path, overrides)
    path.write_text("bundles: [garment.vtb]\nserver:\n  port: 8765\n")
    assert load_config(path, {"server": {"port": 0}}).server.port == 0   # a valid file: the option wins


@pytest.mark.parametrize("doc, message", [
    ({"header_timeout_s": 0}, "server.header_timeout_s"), ({"max_connections": 0}, "server.max_connections"),
    ({"names": ["evil example"]}, "is not a host name"), ({"names": ["kiosk-7.local"]}, None)])
def test_new_server_keys(tmp_path, doc, message):
    from kiosk.service.config import config_from_mapping

    if message is None:
        assert config_from_mapping({"server": doc, "bundles": ["g.vtb"]}).server.names == ("kiosk-7.local",)
    else:
        with pytest.raises(ConfigError, match=message):
            config_from_mapping({"server": doc})


def test_the_command_exits_2_with_one_line(tmp_path):
    deep, port = tmp_path / "deep.yaml", tmp_path / "port.yaml"
    deep.write_text(BAD["deep"])
    port.write_text("server:\n  port: 70000\n")
    for path in (deep, port):
        proc = subprocess.run([sys.executable, "-m", "vtkiosk", "serve", "--config", str(path), "--port", "0",
                               "--exit-after-ready"], cwd=ROOT, capture_output=True, text=True, timeout=300)
        assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr, proc.stderr
