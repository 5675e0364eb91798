"""Every bench record names its CPU the way `engine: auto` and `bench e2e` do (kiosk/inference/cpu.py), so records
taken by different benches on one machine compare."""
from __future__ import annotations

import json

from exporter.bench.environment import environment
from kiosk.inference.cpu import ISA_FLAGS, describe


def test_the_record_names_the_cpu_as_the_runtime_does_and_the_engines_run():
    env = environment(onnxruntime="1.2.3")
    cpu = describe()
    assert (env["cpu"], env["isa"], env["isa_flags"], env["arch"]) == (cpu["model"], cpu["isa"], cpu["flags"],
                                                                        cpu["arch"])
    assert set(env["isa"]) <= set(ISA_FLAGS) and env["onnxruntime"] == "1.2.3"
    assert len(env["loadavg_start"]) == 3 and env["logical_cpus"] >= 1
    json.dumps(env)   # goes into the bench's JSON as it is
