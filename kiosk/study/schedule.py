"""A participant's trial schedule, reproducible from (seed, participant code, session) forever.

Reproducible means on any machine, Python or numpy version: the random stream is SHA-256 in counter mode over a
key built from the seed, the code and the session (never Python's `hash()`, which is salted per process, and not
`random`/numpy generators, whose algorithms may change between versions). The whole schedule is also written to the
log at session start, so the log alone tells what every participant was shown.

Protocol (paper supplement): warm-up trial(s) on the warm-up garment first (untimed, not analysed), then
`test_garments` garments drawn from the rest; for each test garment one trial per comparison (reference against
that condition). Trials are grouped by garment because the real garment lies beside the screen and the operator
swaps it between garments. Both panels of a trial show the same half of the garment. Counterbalancing within a
session: the reference sits on the left in half of the test trials (|left - right| <= 1) overall and within each
comparison, and the left and right garment halves are used equally often (|difference| <= 1).
"""
from __future__ import annotations

import hashlib
from dataclasses import asdict, dataclass
from typing import Any, Sequence

from kiosk.study.config import StudyConfig

ALGORITHM = 1  # bump when the procedure below changes; old logs keep their stored schedules
SIDES = ("left", "right")


class StableRng:
    """Deterministic random integers from SHA-256 in counter mode (portable across platforms and versions)."""

    def __init__(self, key: str) -> None:
        self._key = key.encode("utf-8")
        self._counter = 0

    def u64(self) -> int:
        digest = hashlib.sha256(self._key + b"#" + self._counter.to_bytes(8, "big")).digest()
        self._counter += 1
        return int.from_bytes(digest[:8], "big")

    def below(self, n: int) -> int:
        """Uniform integer in [0, n) (rejection sampling, so no modulo bias)."""
        if n <= 0:
            raise ValueError("below(n) needs n >= 1")
        limit = (1 << 64) - (1 << 64) % n
        while True:
            x = self.u64()
            if x < limit:
                return x % n

    def shuffle(self, items: list) -> list:
        """Fisher-Yates in place; returns the list."""
        for i in range(len(items) - 1, 0, -1):
            j = self.below(i + 1)
            items[i], items[j] = items[j], items[i]
        return items


@dataclass(frozen=True)
class Trial:
    index: int            # 0-based position in the session (warm-up trials first)
    block: str            # "warmup" (untimed, not analysed) or "test"
    garment: str
    comparison: str       # the condition compared against the reference
    left: str             # condition rendered under the left panel
    right: str            # condition rendered under the right panel
    half: str             # garment half shown on both panels: "left" or "right" ("full" in a visual study)

    @property
    def timed(self) -> bool:
        return self.block == "test"

    def side_of(self, condition: str) -> str:
        if condition == self.left:
            return "left"
        if condition == self.right:
            return "right"
        raise ValueError(f"condition {condition!r} is not in trial {self.index}")

    def condition_on(self, side: str) -> str:
        if side not in SIDES:
            raise ValueError(f"side must be 'left' or 'right', got {side!r}")
        return self.left if side == "left" else self.right


@dataclass(frozen=True)
class Schedule:
    study_id: str
    participant: str
    session: int
    seed: int
    reference: str
    trials: tuple[Trial, ...]
    algorithm: int = ALGORITHM

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["trials"] = [asdict(t) for t in self.trials]
        return d

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "Schedule":
        trials = tuple(Trial(**t) for t in d["trials"])
        return cls(study_id=d["study_id"], participant=d["participant"], session=int(d["session"]),
                   seed=int(d["seed"]), reference=d["reference"], trials=trials, algorithm=int(d["algorithm"]))


def _balanced(rng: StableRng, n: int, values: Sequence[str] = SIDES) -> list[str]:
    """n labels, each of two values used floor(n/2) or ceil(n/2) times, in random order."""
    out = [values[0], values[1]] * (n // 2)
    if n % 2:
        out.append(values[rng.below(2)])
    return rng.shuffle(out)


def make_schedule(config: StudyConfig, participant: str, session: int = 1) -> Schedule:
    """The schedule of `participant`'s `session` (1-based); the same inputs always give the same schedule."""
    if session < 1:
        raise ValueError("session numbers start at 1")
    rng = StableRng(f"vtkiosk-study-schedule/v{ALGORITHM}/{config.seed}/{participant}/{session}")
    ref, comps = config.reference, list(config.comparisons)

    pool = rng.shuffle(sorted(config.test_pool))
    test_garments = pool[:config.test_garments]
    plan: list[tuple[str, str]] = []  # (garment, comparison) in presentation order
    for garment in test_garments:
        plan += [(garment, c) for c in rng.shuffle(list(comps))]

    # Reference side: balanced within each comparison, and the odd ones out balanced across comparisons.
    by_comp = {c: [i for i, (_, cc) in enumerate(plan) if cc == c] for c in comps}
    odd = [c for c in comps if len(by_comp[c]) % 2]
    extra = dict(zip(odd, _balanced(rng, len(odd))))
    ref_side: dict[int, str] = {}
    for c in comps:
        idx = by_comp[c]
        sides = ["left", "right"] * (len(idx) // 2) + ([extra[c]] if c in extra else [])
        for i, s in zip(idx, rng.shuffle(sides)):
            ref_side[i] = s
    halves = _balanced(rng, len(plan))

    trials: list[Trial] = []
    warm_comps = rng.shuffle(list(comps))
    for k in range(config.warmup_trials):
        c = warm_comps[k % len(warm_comps)]
        left, right = (ref, c) if rng.below(2) == 0 else (c, ref)
        trials.append(Trial(len(trials), "warmup", config.warmup_garment, c, left, right, SIDES[rng.below(2)]))
    for i, (garment, c) in enumerate(plan):
        left, right = (ref, c) if ref_side[i] == "left" else (c, ref)
        trials.append(Trial(len(trials), "test", garment, c, left, right, halves[i]))
    if config.kind == "visual":
        trials = [Trial(t.index, t.block, t.garment, t.comparison, t.left, t.right, "full") for t in trials]
    return Schedule(study_id=config.id, participant=participant, session=session, seed=config.seed, reference=ref,
                    trials=tuple(trials))
