"""`vtkiosk eval --pool`: stored tables pooled into one comparison. Point estimates are exactly what the tables
hold, a run in two tables counts once, two different runs under one name are refused, and bad files say which."""
import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trainer.bootstrap import single_unit, value
from trainer.eval_cli import main
from trainer.pool import PoolError, load_runs, pool

ROOT = Path(__file__).resolve().parents[2]
RUN5 = ROOT / "docs/compare_gpu/h100-768-2000/compare.json"


def _run(method: str, garment: str, seed: int, outside: float, psnr: float = 25.0) -> dict:
    return {"method": method, "garment": garment, "seed": seed, "step": 2000, "crop": 768, "weights": "average",
            "checkpoint": "latest", "full_angle_deg_outside": outside, "full_fbsifid_unseen": outside / 100,
            "full_angle_deg": outside, "visual_psnr": psnr,
            "gap_closed": {"full_angle_deg": (10.0 - outside) / 8.0},
            "references": {"flat": {"full_angle_deg_outside": 10.0, "full_angle_deg": 10.0},
                           "oracle": {"full_angle_deg_outside": 2.0, "full_angle_deg": 2.0}}}


def _table(path: Path, runs: list[dict]) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"runs": runs}))
    return path


@settings(max_examples=60, deadline=None)
@given(st.sampled_from(["visual_psnr", "full_angle_deg_outside", "visual_ssim"]),
       st.floats(-50, 120, allow_nan=False))
def test_a_single_unit_reduces_to_the_score_it_was_made_from(metric, v):
    """Up to the 120 dB PSNR the scoring reports for identical images (its floor on the MSE)."""
    assert value(metric, single_unit(metric, v)) == pytest.approx(v, rel=1e-12, abs=1e-9)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_a_non_finite_score_is_refused(bad):
    with pytest.raises(ValueError, match="finite"):
        single_unit("full_angle_deg_outside", bad)


def test_two_tables_pool_into_one_with_a_shared_run_counted_once(tmp_path):
    """Seeds 0-2 in one table, 1-3 in another (seed 1 and 2 shared): four seeds a side, means over those four."""
    ours = {0: 5.0, 1: 5.5, 2: 4.5, 3: 5.2}
    base = {0: 6.0, 1: 6.1, 2: 5.9, 3: 6.3}
    runs = lambda seeds: [_run("ours", g, s, ours[s] + i) for i, g in enumerate("AB") for s in seeds] + \
        [_run("base", g, s, base[s] + i) for i, g in enumerate("AB") for s in seeds]
    a = _table(tmp_path / "a/compare.json", runs([0, 1, 2]))
    b = _table(tmp_path / "b/compare.json", runs([1, 2, 3]))
    assert len(load_runs([a, b])) == 16
    md, data = pool([a, b], tmp_path / "out", n_boot=400)
    d = data["differences"]["rows"]["base"]["full_angle_deg_outside"]
    want = np.mean(list(ours.values())) - np.mean(list(base.values()))
    assert d["diff"] == pytest.approx(want) and d["lo"] <= d["diff"] <= d["hi"] and d["hi"] < 0
    assert data["target"]["garments"][0]["runs"] == {"ours": 4, "base": 4}
    assert data["pooled_from"] == [str(a), str(b)]
    assert "Pooled from 2 stored table(s)" in md and "places within a run are not resampled" in md
    assert (tmp_path / "out/compare.md").read_text() == md
    assert json.loads((tmp_path / "out/compare.json").read_text())["mean"]["ours"]["full_angle_deg_outside"] == \
        pytest.approx(np.mean(list(ours.values())) + 0.5)


def test_only_keeps_the_named_rows_and_the_check_counts_only_them(tmp_path):
    """A second treatment of `ours` that beats it would stop the check; with --only it is out of the table."""
    runs = [_run("ours", g, s, 5.0 + s / 10) for g in "AB" for s in range(3)]
    runs += [_run("ours-other", g, s, 4.0 + s / 10) for g in "AB" for s in range(3)]
    runs += [_run("base", g, s, 6.0 + s / 10) for g in "AB" for s in range(3)]
    t = _table(tmp_path / "t/compare.json", runs)
    _, every = pool([t], tmp_path / "all", n_boot=400)
    assert {"ours-other", "base"} <= set(every["differences"]["rows"]) and every["rows_kept"] is None
    md, kept = pool([t], tmp_path / "kept", n_boot=400, only=["ours", "base"])
    assert "base" in kept["differences"]["rows"] and "ours-other" not in kept["differences"]["rows"]
    assert kept["rows_kept"] == ["ours", "base"]
    assert "Rows kept: ours, base." in md
    assert kept["target"]["garments"][0]["runs"] == {"ours": 3, "base": 3}


@pytest.mark.parametrize("only, message", [
    (["ours", "nosuch"], "no table holds: nosuch"),
    (["base"], "leaves out --ours 'ours'"),
])
def test_only_naming_a_missing_row_or_leaving_out_ours_is_refused(tmp_path, capsys, only, message):
    t = _table(tmp_path / "t.json", [_run("ours", "A", 0, 5.0), _run("base", "A", 0, 6.0)])
    with pytest.raises(PoolError, match=message):
        pool([t], tmp_path / "out", only=only)
    assert main(["--pool", str(t), "--only", *only, "--out", str(tmp_path / "out")]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_only_without_pool_is_a_usage_error(tmp_path):
    with pytest.raises(SystemExit) as exc:
        main(["--compare", str(tmp_path / "r"), "--only", "ours"])
    assert exc.value.code == 2


def test_garments_reads_only_theirs_so_a_check_pools_its_parts_from_different_tables(tmp_path):
    """Garment B's seed 0 was trained again on another machine (other scores): both tables at once are refused, but
    A from the first and B from the second, each pooled on its garment, pool into the check of both."""
    first = _table(tmp_path / "first.json", [_run(m, g, s, v + s / 10) for g in "AB" for s in range(3)
                                             for m, v in (("ours", 5.0), ("base", 6.0))])
    again = _table(tmp_path / "again.json", [_run(m, "B", s, v + s / 7) for s in range(3)
                                             for m, v in (("ours", 4.0), ("base", 6.5))])
    with pytest.raises(PoolError, match="two runs under one name"):
        load_runs([first, again])
    assert {r["garment"] for r in load_runs([first, again], ["A"])} == {"A"}
    md_a, a = pool([first, again], tmp_path / "a", n_boot=400, garments=["A"])
    _, b = pool([again], tmp_path / "b", n_boot=400, garments=["B"])
    assert "Garments kept: A." in md_a and a["garments_kept"] == ["A"]
    _, both = pool([tmp_path / "a/compare.json", tmp_path / "b/compare.json"], tmp_path / "both", n_boot=400)
    assert [g["garment"] for g in both["target"]["garments"]] == ["A", "B"]
    assert [g["runs"] for g in both["target"]["garments"]] == [{"ours": 3, "base": 3}] * 2
    d = both["differences"]["rows"]["base"]["full_angle_deg_outside"]["diff"]
    assert d == pytest.approx(np.mean([-1.0, -2.5]))


def test_garments_matches_the_fabric_inside_a_full_id(tmp_path):
    t = _table(tmp_path / "t.json", [_run("ours", "singleskit_SatinShirt_padded_900_x1", 0, 5.0),
                                     _run("ours", "singleskit_KnitJacket_padded_900_x1", 0, 6.0)])
    assert [r["garment"] for r in load_runs([t], ["SatinShirt"])] == ["singleskit_SatinShirt_padded_900_x1"]
    assert len(load_runs([t], ["singleskit_KnitJacket_padded_900_x1", "SatinShirt"])) == 2


@pytest.mark.parametrize("garments", [["Satin"], ["KnitJacket", "Nosuch"]])
def test_garments_naming_no_garment_is_refused(tmp_path, capsys, garments):
    t = _table(tmp_path / "t.json", [_run("ours", "singleskit_KnitJacket_padded_900_x1", 0, 5.0),
                                     _run("base", "singleskit_KnitJacket_padded_900_x1", 0, 6.0)])
    with pytest.raises(PoolError, match="no table holds"):
        load_runs([t], garments)
    assert main(["--pool", str(t), "--garments", *garments, "--out", str(tmp_path / "out")]) == 2
    assert "--garments names garment(s) no table holds" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_garments_without_pool_is_a_usage_error(tmp_path):
    with pytest.raises(SystemExit) as exc:
        main(["--compare", str(tmp_path / "r"), "--garments", "SatinShirt"])
    assert exc.value.code == 2


def test_two_different_runs_under_one_name_are_refused(tmp_path):
    a = _table(tmp_path / "a.json", [_run("ours", "A", 0, 5.0)])
    b = _table(tmp_path / "b.json", [_run("ours", "A", 0, 5.4)])
    with pytest.raises(PoolError, match="also in .*a.json with other scores"):
        load_runs([a, b])


@pytest.mark.parametrize("content, message", [
    ("{not json", "cannot read a comparison table"),
    ('{"mean": {}}', "no 'runs' list"),
    ('{"runs": [{"garment": "A"}]}', "run 0 has no method and garment"),
    ('{"runs": [{"method": "ours", "garment": "A", "full_angle_deg_outside": "7"}]}', "has no finite score"),
])
def test_a_bad_table_is_named_with_what_is_wrong_and_the_cli_exits_2(tmp_path, capsys, content, message):
    bad = tmp_path / "bad.json"
    bad.write_text(content)
    with pytest.raises(PoolError, match=message):
        load_runs([bad])
    assert main(["--pool", str(bad), "--out", str(tmp_path / "out")]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_a_missing_table_is_named(tmp_path):
    with pytest.raises(PoolError, match="missing.json: cannot read"):
        load_runs([tmp_path / "missing.json"])


@pytest.mark.parametrize("table, ours", [(RUN5, "ours")] + [
    (ROOT / f"docs/compare_1k/mirrors/{t}/compare.json", "txr-lift")
    for t in ("blind_cd", "blind_dn", "blind_kn", "blind_ss", "blind_cd_cpu", "blind_cd_cpu_u23", "blind2_kn",
              "blind2_ss", "blind2_ct", "blind2_dn")])
def test_pooling_a_committed_table_gives_its_point_estimates(tmp_path, table, ours):
    """The stored runs' scores reproduce the hierarchical table's differences exactly; only intervals differ."""
    stored = json.loads(table.read_text())
    _, data = pool([table], tmp_path / "out", n_boot=200, ours=ours)
    for x, row in stored["differences"]["rows"].items():
        for k, d in row.items():
            assert data["differences"]["rows"][x][k]["diff"] == pytest.approx(d["diff"], rel=1e-9, abs=1e-12), (x, k)
    for g_new, g_old in zip(data["target"]["garments"], stored["target"]["garments"]):
        assert g_new["garment"] == g_old["garment"] and g_new["runs"] == g_old["runs"]
        assert g_new["gap_closed"] == pytest.approx(g_old["gap_closed"])
    assert (tmp_path / "out" / "target.png").is_file() and data["target_plot"].endswith("target.png")


@pytest.mark.parametrize("table, ours", [("docs/compare_gpu/h100-768-2000/pooled", "ours"),
                                         ("docs/compare_1k/mirrors/satin_6seeds", "txr-energy-none"),
                                         ("docs/compare_1k/mirrors/all4_lift/cdk", "txr-lift"),
                                         ("docs/compare_1k/mirrors/all4_lift", "txr-lift"),
                                         ("docs/compare_1k/mirrors/all4_blind", "txr-lift")])
def test_the_committed_pooled_table_is_what_pool_makes_of_its_committed_inputs(tmp_path, table, ours):
    """Each was written by a `--pool` command (the README's; docs/training.md "SatinShirt on six seeds", with
    --only; "One gain rule for the four garments", with --garments, then pooling the parts; "A blind test of
    `lift`", the four garments' blind tables) from committed tables; the bootstrap is seeded, so the same command
    gives the same figures."""
    stored = json.loads((ROOT / table / "compare.json").read_text())
    _, data = pool([ROOT / p for p in stored["pooled_from"]], tmp_path / "out", ours=ours,
                   only=stored.get("rows_kept"), garments=stored.get("garments_kept"))
    assert data["differences"] == stored["differences"]
    assert data["target"] == stored["target"]
    assert all(not p.startswith("/") for p in stored["pooled_from"])
