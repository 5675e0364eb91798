"""What a benchmark record says about the machine it was taken on: the CPU (kiosk/inference/cpu.py, the one reader of
/proc/cpuinfo), the Python and library versions, and the load average when it started (these machines are shared,
so a figure taken under load says so)."""
from __future__ import annotations

import os
import platform

import numpy as np

from kiosk.inference.cpu import describe


def environment(**versions: str) -> dict:
    """The record's `env`; `versions` adds the engines the bench ran (e.g. onnxruntime=ort.__version__)."""
    cpu = describe()
    return {"cpu": cpu["model"], "isa": cpu["isa"], "isa_flags": cpu["flags"], "arch": cpu["arch"],
            "logical_cpus": os.cpu_count(), "python": platform.python_version(), "platform": platform.platform(),
            "numpy": np.__version__, **versions, "loadavg_start": list(os.getloadavg())}
