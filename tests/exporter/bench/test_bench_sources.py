"""Paths a benchmark writes into its JSON: those JSONs get committed, so no path of this machine goes in."""
from pathlib import Path

from exporter.bench.sources import portable


def test_inside_the_working_directory_is_relative(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "runs" / "a").mkdir(parents=True)
    assert portable(tmp_path / "runs" / "a" / "b.vtb") == "runs/a/b.vtb"
    assert portable("runs/a") == "runs/a"


def test_outside_keeps_only_the_name(tmp_path, monkeypatch):
    (tmp_path / "work").mkdir()
    monkeypatch.chdir(tmp_path / "work")
    out = portable(tmp_path / "keys" / "denim.vtb")
    assert out == "<outside>/denim.vtb" and str(tmp_path) not in out
    assert portable(None) is None
    assert portable(Path("..") / "x.vtb") == "<outside>/x.vtb"
