"""A run records the machine and kernel path of each stretch it was trained in, and says so when a resume changes it."""
from __future__ import annotations

import json

import pytest
import torch
from hypothesis import given, settings, strategies as st

from kiosk.inference.cpu import ISA_FLAGS
from trainer import provenance
from trainer.checkpoint import load_generator
from trainer.compare import machines, machines_markdown, table
from trainer.config import load_config
from trainer.data.synthetic import generate_dataset
from trainer.loop import Trainer

torch.set_num_threads(2)
HERE = provenance.this_machine(1)
# Another kernel path than this machine's, whichever ISA this machine has (CI runs on AVX2-only and AVX-512 hosts).
OTHER_KERNELS = ({"isa": ["avx2"], "torch_cpu_capability": "AVX2"} if HERE["torch_cpu_capability"] != "AVX2"
                 else {"isa": ["avx2", "avx512"], "torch_cpu_capability": "AVX512"})


@pytest.fixture(scope="module")
def garment(tmp_path_factory):
    root = tmp_path_factory.mktemp("synth")
    generate_dataset(root, garments=1, seed=0, frame=(192, 144), progress=False)
    return next(p for p in root.iterdir() if p.is_dir())


def test_this_machine_names_the_cpu_and_torchs_kernel_path():
    assert HERE["cpu_model"] and HERE["threads"] == 1 and HERE["torch"] == torch.__version__
    assert HERE["torch_cpu_capability"] == torch.backends.cpu.get_cpu_capability()
    assert set(HERE["isa"]) <= set(ISA_FLAGS)
    json.dumps(HERE)   # it goes into checkpoints and compare.json


def test_same_kernels_continues_the_stretch_silently():
    stretches = [{"from_step": 0, "machine": dict(HERE)}]
    out, warning = provenance.continue_record(stretches, 500, dict(HERE))
    assert out == stretches and warning is None


@pytest.mark.parametrize("key,value", [("isa", OTHER_KERNELS["isa"]),
                                       ("torch_cpu_capability", OTHER_KERNELS["torch_cpu_capability"]), ("threads", 4),
                                       ("cpu_model", "Intel(R) Xeon(R) Platinum 8480+"), ("torch", "2.12.0+cpu")])
def test_a_resume_on_other_kernels_starts_a_stretch_and_warns(key, value):
    other = HERE | {key: value}
    out, warning = provenance.continue_record([{"from_step": 0, "machine": other}], 700, dict(HERE))
    assert [s["from_step"] for s in out] == [0, 700] and out[-1]["machine"] == HERE
    assert "step 700" in warning and "not bit-identical" in warning
    assert provenance.summary(other) in warning and provenance.summary(HERE) in warning


def test_a_run_from_before_the_records_gets_an_unrecorded_first_stretch():
    out, warning = provenance.continue_record(None, 141, dict(HERE))
    assert out == [{"from_step": 0, "machine": None}, {"from_step": 141, "machine": HERE}]
    assert "unrecorded" in warning and "not bit-identical" not in warning
    assert provenance.summary(None) == "unrecorded"


machine = st.fixed_dictionaries({"cpu_model": st.sampled_from(["AMD EPYC", "Intel Xeon"]),
                                 "isa": st.sampled_from([["avx2"], ["avx2", "avx512"]]),
                                 "torch": st.just("2.13.0+cpu"),
                                 "torch_cpu_capability": st.sampled_from(["AVX2", "AVX512"]),
                                 "threads": st.integers(1, 2)})


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 200), machine), min_size=1, max_size=8))
def test_stretches_stay_ordered_and_end_on_this_machine(resumes):
    stretches, step = None, 0
    for gap, m in resumes:
        step += gap
        before = stretches[-1]["machine"] if stretches else None
        fresh = stretches is None and step == 0
        stretches, warning = provenance.continue_record(stretches, step, m)
        assert stretches[-1]["machine"] == m
        assert (warning is None) == (fresh or provenance.same_kernels(before, m))
    starts = [s["from_step"] for s in stretches]
    assert starts == sorted(starts) and starts[0] == 0
    assert all(not provenance.same_kernels(a["machine"], b["machine"]) for a, b in zip(stretches, stretches[1:]))


def test_checkpoints_and_metrics_carry_the_machine_and_a_changed_resume_is_recorded(garment, tmp_path, caplog):
    cfg = load_config("tiny", overrides=["train.steps=2", "train.ckpt_every=1", "train.threads=1"])
    Trainer(cfg, garment, tmp_path / "r").run(until=1)
    _, info = load_generator(tmp_path / "r", "latest")
    assert info["machines"] == [{"from_step": 0, "machine": HERE}]
    # pretend the first stretch ran on a machine with the other kernel path
    path = tmp_path / "r" / "checkpoints" / "latest.pt"
    ck = torch.load(path, weights_only=False)
    ck["machines"][0]["machine"] = HERE | OTHER_KERNELS
    torch.save(ck, path)
    with caplog.at_level("WARNING", logger="trainer"):
        t = Trainer(cfg, garment, tmp_path / "r", resume=True)
    assert "resuming at step 1" in caplog.text and OTHER_KERNELS["torch_cpu_capability"] in caplog.text
    t.run()
    record = json.loads((tmp_path / "r" / "metrics.json").read_text())["train"]["machines"]
    assert [s["from_step"] for s in record] == [0, 1] and record[1]["machine"] == HERE
    _, info = load_generator(tmp_path / "r", "latest")
    assert info["machines"] == record


def test_the_comparison_names_the_machines_its_rows_were_trained_on():
    other = HERE | OTHER_KERNELS
    results = [{"method": "ours", "garment": "G", "machines": [{"from_step": 0, "machine": HERE}]},
               {"method": "ours", "garment": "H", "machines": [{"from_step": 0, "machine": HERE},
                                                              {"from_step": 9, "machine": other}]},
               {"method": "flat-ish", "garment": "G"}]
    got = machines(results)
    assert got["machines"] == {provenance.summary(HERE): 2, provenance.summary(other): 1, "unrecorded": 1}
    assert got["runs_resumed_across_machines"] == 1 and got["runs_resumed_after_unrecorded"] == 0
    md = machines_markdown(got)
    assert "1 run(s) were resumed on another kernel path" in md and "differ by more than the intervals" in md
    one = machines(results[:1])
    assert "differ" not in machines_markdown(one) and provenance.summary(HERE) in machines_markdown(one)
    md, data = table(results[:1])
    assert provenance.summary(HERE) in md and data["trained_on"] == one


def test_a_run_begun_unrecorded_is_not_called_resumed_on_another_kernel_path():
    results = [{"method": "ours", "garment": "G", "machines": [{"from_step": 0, "machine": None},
                                                              {"from_step": 141, "machine": HERE}]},
               {"method": "ours", "garment": "H", "machines": [{"from_step": 0, "machine": HERE}]}]
    got = machines(results)
    assert got["runs_resumed_across_machines"] == 0 and got["runs_resumed_after_unrecorded"] == 1
    md = machines_markdown(got)
    assert "another kernel path" not in md and "1 run(s) began on an unrecorded machine" in md
