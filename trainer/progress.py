"""Training progress for people: a bar on a terminal, a plain line every half minute elsewhere (logs, CI, Slurm).

Shows step, the main losses, seconds per step and the time left, so a long run never looks hung.
"""
from __future__ import annotations

import sys
import time

SHOWN = ("g_total", "v_l1", "t_l1", "t_gan", "d_visual", "d_tactile", "l1", "d")


def _eta(seconds: float) -> str:
    s = int(max(seconds, 0))
    return f"{s // 3600}h{s % 3600 // 60:02d}m" if s >= 3600 else f"{s // 60}m{s % 60:02d}s"


class Progress:
    def __init__(self, *, total: int, initial: int, desc: str, stream=None, every_s: float = 30.0,
                 tty: bool | None = None):
        self.stream = stream or sys.stderr
        self.total, self.step, self.desc = total, initial, desc
        self.start_step, self.t0 = initial, time.perf_counter()
        self.every_s, self.last = every_s, self.t0
        self.losses: dict[str, float] = {}
        tty = self.stream.isatty() if tty is None else tty
        self.bar = None
        if tty:
            from tqdm import tqdm
            self.bar = tqdm(total=total, initial=initial, desc=desc, dynamic_ncols=True, file=self.stream)

    def seconds_per_step(self) -> float:
        done = self.step - self.start_step
        return (time.perf_counter() - self.t0) / done if done else float("nan")

    def losses_seen(self, logs: dict[str, float]) -> None:
        self.losses = {k: v for k, v in logs.items() if k in SHOWN}
        if self.bar is not None:
            self.bar.set_postfix({k: f"{v:.3g}" for k, v in self.losses.items()})

    def update(self, n: int = 1) -> None:
        self.step += n
        if self.bar is not None:
            self.bar.update(n)
            return
        now = time.perf_counter()
        if now - self.last >= self.every_s or self.step == self.total:
            self.last = now
            self.stream.write(self.line() + "\n")
            self.stream.flush()

    def line(self) -> str:
        sps = self.seconds_per_step()
        left = "?" if sps != sps else _eta(sps * (self.total - self.step))
        losses = " ".join(f"{k} {v:.3g}" for k, v in self.losses.items())
        return (f"{self.desc}: step {self.step}/{self.total} {losses} "
                f"({sps:.2f} s/step, {left} left)").replace("  ", " ")

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
