"""Which CPU this is: model name and the instruction-set features that decide engine speed.

Engine speed order depends on the ISA (AVX2 vs AVX-512, VNNI for int8, AMX, NEON on ARM), so every benchmark
record and every `engine: auto` choice carries it; a figure without the CPU it was taken on cannot be compared.
"""
from __future__ import annotations

import os
import platform
from pathlib import Path

# family -> the /proc/cpuinfo flags (x86 "flags", ARM "Features") that show it
ISA_FLAGS = {"avx2": ("avx2",), "avx512": ("avx512f",), "vnni": ("avx512_vnni", "avx_vnni"),
             "amx": ("amx_tile", "amx_int8", "amx_bf16"), "neon": ("asimd", "neon")}


def describe(cpuinfo: str | None = None) -> dict:
    """{"model", "arch", "logical_cpus", "isa": [families present], "flags": [the matching raw flags]}."""
    if cpuinfo is None:
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text(errors="replace")
        except OSError:
            cpuinfo = ""
    model, flags = "", set()
    for line in cpuinfo.splitlines():
        key, _, value = line.partition(":")
        key = key.strip().lower()
        if key in ("model name", "hardware", "cpu model") and not model:
            model = value.strip()
        elif key in ("flags", "features"):
            flags.update(value.split())
    arch = platform.machine()
    if arch in ("aarch64", "arm64"):
        flags.add("neon")  # Advanced SIMD is mandatory on AArch64, whether or not the kernel lists it
    isa = [fam for fam, names in ISA_FLAGS.items() if flags.intersection(names)]
    raw = sorted(flags.intersection(f for names in ISA_FLAGS.values() for f in names))
    return {"model": model or platform.processor() or arch, "arch": arch, "logical_cpus": os.cpu_count(),
            "isa": isa, "flags": raw}
