"""Which machine trained each stretch of a run: CPU model, ISA, torch and the kernel path torch chose.

The same training command on another CPU picks other kernels (torch dispatches AVX-512 or AVX2 code by what the CPU
has), and the run comes out different: docs/training.md measured up to 0.44 deg of outside angle between two such
runs with identical data. `--resume` is bit-identical only on the same kernel path, so a run keeps one record per
stretch it was trained in, and a resume on different kernels says so instead of passing silently.
"""
from __future__ import annotations

import torch

from kiosk.inference.cpu import describe

# what decides the arithmetic: the same values here mean the same kernels (and so the same run, given the seed)
KERNEL_KEYS = ("cpu_model", "isa", "torch", "torch_cpu_capability", "threads", "gpu")


def this_machine(threads: int, device: torch.device | None = None) -> dict:
    """The record of this machine; `gpu` (name, compute capability) only when the step runs on one."""
    cpu = describe()
    out = {"cpu_model": cpu["model"], "arch": cpu["arch"], "isa": cpu["isa"], "torch": torch.__version__,
           "torch_cpu_capability": torch.backends.cpu.get_cpu_capability(), "threads": int(threads)}
    if device is not None and device.type == "cuda":
        major, minor = torch.cuda.get_device_capability(device)
        out["gpu"] = f"{torch.cuda.get_device_name(device)} (sm_{major}{minor}, CUDA {torch.version.cuda})"
    return out


def same_kernels(a: dict | None, b: dict | None) -> bool:
    """False when either record is missing: a stretch trained on an unrecorded machine cannot be vouched for."""
    if not a or not b:
        return False
    return all(a.get(k) == b.get(k) for k in KERNEL_KEYS)


def continue_record(stretches: list[dict] | None, step: int, here: dict) -> tuple[list[dict], str | None]:
    """The run's stretches after resuming at `step` on `here`, and a warning when the kernels changed (or the
    run predates these records). A stretch is {"from_step": n, "machine": record or None}."""
    stretches = list(stretches or [])
    if not stretches:
        stretches = [{"from_step": 0, "machine": None}]
        if step == 0:
            return [{"from_step": 0, "machine": here}], None
    last = stretches[-1]["machine"]
    if same_kernels(last, here):
        return stretches, None
    stretches.append({"from_step": int(step), "machine": here})
    if last is None:
        return stretches, (f"resuming at step {step} on {summary(here)}; the run so far was trained on an unrecorded "
                           "machine, so nothing vouches that the continuation matches an uninterrupted run")
    return stretches, (f"resuming at step {step} on {summary(here)}, but the run so far was trained on "
                       f"{summary(last)}: the continuation is not bit-identical to an uninterrupted run")


def summary(m: dict | None) -> str:
    """One line: `AMD EPYC (avx2+avx512; torch 2.13.0+cpu AVX512, 1 thread)`."""
    if not m:
        return "unrecorded"
    isa = "+".join(m.get("isa") or []) or "no SIMD flags"
    t = m.get("threads")
    gpu = f" on {m['gpu']}" if m.get("gpu") else ""
    return (f"{m.get('cpu_model', '?')} ({isa}; torch {m.get('torch', '?')} {m.get('torch_cpu_capability', '?')}, "
            f"{t} thread{'s' if t != 1 else ''}){gpu}")
