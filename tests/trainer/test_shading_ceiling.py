"""scripts/shading_ceiling.py: on a hard synthetic garment the true relief explains part of its photo's fine
shading, no relief explains none, and a folder it cannot read is a clear error."""
from __future__ import annotations

import pytest

from tests.scripts_module import load_script


@pytest.fixture(scope="module")
def sc():
    return load_script("shading_ceiling")


def test_the_truth_explains_more_than_no_relief(sc, hard_one, capsys):
    folder = next(p for p in hard_one.iterdir() if p.is_dir())
    rows = sc.ceiling(folder)
    assert set(rows) == {"truth", "truth without weave", "flat"}
    assert rows["flat"] == [1.0, 1.0]
    assert all(0 <= t < 0.95 for t in rows["truth"])
    name = folder.name.split("_")[1]
    assert sc.main([str(hard_one), name]) == 0
    assert name in capsys.readouterr().out


def test_an_unknown_garment_is_refused(sc, hard_one, capsys):
    assert sc.main([str(hard_one), "NoSuchFabric"]) == 2
    assert "no garment folder" in capsys.readouterr().err
