"""A bundle names its training run without the build machine's paths."""
from __future__ import annotations

from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st

from exporter.export import source_run_name
from kiosk.bundle.manifest import manifest_from_dict, manifest_to_dict
from tests.kiosk.bundle_factory import base_manifest


def _doc(**overrides) -> dict:
    m = base_manifest(**overrides)
    files = {g.file: "0" * 64 for g in m.graphs.values()} | {p: "0" * 64 for p in m.assets.values()}
    return manifest_to_dict(base_manifest(files=files, **overrides))


def test_a_run_under_the_runs_root_is_named_relative_to_it(tmp_path):
    run = tmp_path / "runs" / "denim" / "ours-seed0"
    run.mkdir(parents=True)
    assert source_run_name(run, tmp_path) == "runs/denim/ours-seed0"
    assert source_run_name(run, tmp_path / "runs") == "denim/ours-seed0"


def test_a_run_elsewhere_is_a_hash_of_its_path(tmp_path):
    run = tmp_path / "elsewhere" / "run"
    run.mkdir(parents=True)
    name = source_run_name(run, tmp_path / "runs")
    assert name.startswith("sha256:") and len(name) == len("sha256:") + 16 and str(tmp_path) not in name
    assert name == source_run_name(run, tmp_path / "runs") != source_run_name(tmp_path, tmp_path / "runs")


@settings(max_examples=50, deadline=None)
@given(st.lists(st.from_regex(r"\A[a-z0-9][a-z0-9_-]{0,8}\Z"), min_size=1, max_size=4))
def test_the_recorded_name_never_holds_an_absolute_path_and_the_manifest_takes_it(parts):
    root = Path("/nonexistent-root")
    for run in (root.joinpath(*parts), Path("/other").joinpath(*parts)):
        name = source_run_name(run, root)
        assert not name.startswith("/") and ".." not in name.split("/")
        doc = _doc(source_run=name)
        assert manifest_from_dict(doc).source_run == name
