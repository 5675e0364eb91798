"""Seeded, deterministic fault injection on reports (one `FaultInjector` per link direction).

For a report entering the link at modelled/real time `t`, `apply` returns the deliveries [(time, bytes), ...]:
dropped (none), corrupted (1-3 random bytes XOR a random non-zero value), duplicated (twice), reordered (held back
by `reorder_gap_s`, so the next report overtakes it), delayed (`delay_s` late). `stall` makes the device deaf and
mute for `stall_s` (handled by the link). The same seed and the same report sequence give the same faults.
"""
from __future__ import annotations

import random
from collections import Counter

from ..config import FaultConfig


class FaultInjector:
    def __init__(self, faults: FaultConfig, stream: int, reorder_gap_s: float) -> None:
        self.faults = faults
        self.rng = random.Random(faults.seed * 2 + stream)
        self.reorder_gap_s = reorder_gap_s
        self.counts: Counter[str] = Counter()

    def stall(self) -> bool:
        f = self.faults
        if f.stall and self.rng.random() < f.stall:
            self.counts["stall"] += 1
            return True
        return False

    def apply(self, report: bytes, t: float) -> list[tuple[float, bytes]]:
        f = self.faults
        if not f.any:
            return [(t, report)]
        r = self.rng
        if r.random() < f.drop:
            self.counts["drop"] += 1
            return []
        if r.random() < f.corrupt and report:
            self.counts["corrupt"] += 1
            buf = bytearray(report)
            for _ in range(r.randint(1, 3)):
                buf[r.randrange(len(buf))] ^= r.randint(1, 255)
            report = bytes(buf)
        if r.random() < f.reorder:
            self.counts["reorder"] += 1
            t += self.reorder_gap_s
        if r.random() < f.delay:
            self.counts["delay"] += 1
            t += f.delay_s
        out = [(t, report)]
        if r.random() < f.duplicate:
            self.counts["duplicate"] += 1
            out.append((t, report))
        return out
