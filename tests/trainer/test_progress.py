"""Training progress: plain periodic lines off a terminal (step, losses, s/step, time left), a bar on one."""
from __future__ import annotations

import io

from trainer.progress import Progress


def test_plain_lines_when_not_a_terminal():
    out = io.StringIO()
    p = Progress(total=3, initial=0, desc="ours:denim", stream=out, every_s=0.0, tty=False)
    for _ in range(3):
        p.losses_seen({"g_total": 1.5, "t_l1": 0.25, "not_shown": 9.0})
        p.update()
    p.close()
    lines = out.getvalue().splitlines()
    assert len(lines) == 3 and lines[-1].startswith("ours:denim: step 3/3 g_total 1.5 t_l1 0.25 (")
    assert "s/step" in lines[-1] and "left)" in lines[-1] and "not_shown" not in out.getvalue()


def test_quiet_between_intervals_but_always_reports_the_last_step():
    out = io.StringIO()
    p = Progress(total=50, initial=10, desc="x", stream=out, every_s=3600.0, tty=False)
    for _ in range(40):
        p.update()
    assert out.getvalue().count("\n") == 1 and "step 50/50" in out.getvalue()


def test_bar_on_a_terminal():
    class Tty(io.StringIO):
        def isatty(self):
            return True
    out = Tty()
    p = Progress(total=5, initial=0, desc="bar", stream=out)
    p.losses_seen({"g_total": 2.0})
    p.update(5)
    p.close()
    assert "5/5" in out.getvalue() and "g_total=2" in out.getvalue()
