"""Messages an operator acts on: each names the real problem and the real remedy."""
from __future__ import annotations

import socket

import pytest

from kiosk.bundle.store import BundleStore
from kiosk.contract.errors import KioskError
from kiosk.service.config import config_from_mapping
from kiosk.service.daemon import KioskDaemon
from kiosk.service.server import KioskServer
from vtkiosk.cli import main as vtkiosk


def test_bundle_list_of_a_missing_store_fails_and_says_so(tmp_path, capsys):
    rc = vtkiosk(["bundle", "list", "--store", str(tmp_path / "typo")])
    err = capsys.readouterr().err
    assert rc == 2 and "no bundle store at" in err and "typo" in err
    (tmp_path / "real").mkdir()                                           # an existing, empty store is fine
    assert vtkiosk(["bundle", "list", "--store", str(tmp_path / "real")]) == 0
    assert "no bundles installed" in capsys.readouterr().out


def test_serving_an_empty_store_says_how_to_fill_it(tmp_path):
    store = tmp_path / "store"
    BundleStore(store, None, allow_unsigned=True)
    cfg = config_from_mapping({"store": {"root": str(store), "allow_unsigned": True}, "state_dir": str(tmp_path / "s"),
                               "server": {"port": 0}, "device": {"type": "emulated"}})
    daemon = KioskDaemon(cfg)
    with pytest.raises(KioskError, match="nothing to serve") as info:
        daemon.start()
    assert "vtkiosk bundle install" in str(info.value) and "none configured" not in str(info.value)
    daemon.stop()


def test_a_busy_port_names_both_ways_to_choose_another():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        server = KioskServer("127.0.0.1", s.getsockname()[1])
        with pytest.raises(KioskError, match=r"--port, or server.port"):
            server.start()
