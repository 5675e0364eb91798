"""Counters, gauges and latency histograms for `GET /metrics`, rendered as Prometheus text format 0.0.4.

No global registry: the daemon creates one `Registry` and hands it to whatever records metrics, so tests and two
daemons in one process never share numbers. Every method is thread-safe (one lock per metric; recording is a dict
update under it). Names, label names and values are checked when used, so a typo fails loudly instead of
producing a series nobody scrapes.

Example:
    >>> reg = Registry()
    >>> frames = reg.counter("vtkiosk_frames_total", "Frames committed to the haptic device.", labels=("panel",))
    >>> frames.inc(panel="main")
    >>> print(reg.render().splitlines()[2])
    vtkiosk_frames_total{panel="main"} 1.0
"""
from __future__ import annotations

import abc
import bisect
import math
import re
import threading
from collections.abc import Callable, Iterable, Sequence

from kiosk.contract.errors import KioskError

# Seconds; covers a fast cached frame (1 ms) to a stalled inference (10 s), finer around the 100 ms goal.
DEFAULT_LATENCY_BUCKETS: tuple[float, ...] = (0.001, 0.0025, 0.005, 0.01, 0.02, 0.035, 0.05, 0.075, 0.1, 0.15,
                                              0.25, 0.5, 1.0, 2.5, 5.0, 10.0)

_NAME_RE = re.compile(r"^[a-zA-Z_:][a-zA-Z0-9_:]*$")
_LABEL_RE = re.compile(r"^[a-zA-Z_][a-zA-Z0-9_]*$")
_RESERVED_LABELS = {"le", "quantile"}


class MetricError(KioskError, ValueError):
    """A metric was declared or used in a way that would give a wrong or unscrapable series."""


def format_value(v: float) -> str:
    """A sample value the way Prometheus parses it: NaN, +Inf, -Inf or a float literal."""
    if math.isnan(v):
        return "NaN"
    if math.isinf(v):
        return "+Inf" if v > 0 else "-Inf"
    return repr(float(v))


def escape_label_value(value: str) -> str:
    return value.replace("\\", "\\\\").replace("\n", "\\n").replace('"', '\\"')


def escape_help(text: str) -> str:
    return text.replace("\\", "\\\\").replace("\n", "\\n")


def _label_text(names: Sequence[str], values: Sequence[str], extra: str = "") -> str:
    parts = [f'{n}="{escape_label_value(v)}"' for n, v in zip(names, values)]
    if extra:
        parts.append(extra)
    return "{" + ",".join(parts) + "}" if parts else ""


class _Metric(abc.ABC):
    kind = ""

    def __init__(self, name: str, help: str, labels: Iterable[str]):
        if not _NAME_RE.match(name):
            raise MetricError(f"metric name {name!r} is not a valid Prometheus name ([a-zA-Z_:][a-zA-Z0-9_:]*)")
        self.labels = tuple(labels)
        for label in self.labels:
            if not _LABEL_RE.match(label) or label.startswith("__") or label in self._reserved():
                raise MetricError(f"metric {name}: {label!r} cannot be a label name")
        if len(set(self.labels)) != len(self.labels):
            raise MetricError(f"metric {name}: label names repeat: {self.labels}")
        self.name, self.help = name, help
        self._lock = threading.Lock()

    def _reserved(self) -> set[str]:
        return set()

    def _key(self, labels: dict[str, object]) -> tuple[str, ...]:
        if set(labels) != set(self.labels):
            raise MetricError(f"metric {self.name} takes labels {list(self.labels)}; got {sorted(labels)}")
        return tuple(str(labels[n]) for n in self.labels)

    @abc.abstractmethod
    def _samples(self) -> list[str]:
        """The metric's sample lines in exposition format."""

    def render(self) -> str:
        head = f"# HELP {self.name} {escape_help(self.help)}\n# TYPE {self.name} {self.kind}\n"
        return head + "".join(line + "\n" for line in self._samples())


class _Valued(_Metric):
    """One number a label set, set here or read from a function at each render (what counters and gauges share)."""

    def __init__(self, name: str, help: str, labels: Iterable[str] = ()):
        super().__init__(name, help, labels)
        self._values: dict[tuple[str, ...], float] = {} if self.labels else {(): 0.0}
        self._functions: dict[tuple[str, ...], Callable[[], float]] = {}

    def set_function(self, fn: Callable[[], float], **labels: object) -> None:
        """Read the value from `fn` at each render (resident memory, a total the fleet sync job keeps in its state
        file); an exception renders NaN."""
        key = self._key(labels)
        with self._lock:
            self._functions[key] = fn
            self._values.pop(key, None)

    def value(self, **labels: object) -> float:
        key = self._key(labels)
        with self._lock:
            fn = self._functions.get(key)
            if fn is None:
                return self._values.get(key, 0.0)
        return self._call(fn)

    @staticmethod
    def _call(fn: Callable[[], float]) -> float:
        try:
            return float(fn())
        except Exception:  # noqa: BLE001 - a broken probe must not break the whole scrape
            return math.nan

    def _samples(self) -> list[str]:
        with self._lock:
            items = dict(self._values)
            fns = dict(self._functions)
        items.update({k: self._call(fn) for k, fn in fns.items()})
        return [f"{self.name}{_label_text(self.labels, k)} {format_value(v)}" for k, v in sorted(items.items())]


class Counter(_Valued):
    """Only goes up (frames, errors, retries); Prometheus derives rates from it."""

    kind = "counter"

    def inc(self, amount: float = 1.0, **labels: object) -> None:
        amount = float(amount)
        if not math.isfinite(amount) or amount < 0:
            raise MetricError(f"counter {self.name} can only increase by a finite amount >= 0; got {amount}")
        key = self._key(labels)
        with self._lock:
            if key in self._functions:
                raise MetricError(f"counter {self.name}{dict(labels)} is read from a function; it cannot be inc'd")
            self._values[key] = self._values.get(key, 0.0) + amount


class Gauge(_Valued):
    """A value that goes up and down (device link up, RSS, queue depth); may be read lazily from a function."""

    kind = "gauge"

    def set(self, value: float, **labels: object) -> None:
        key = self._key(labels)
        with self._lock:
            self._functions.pop(key, None)
            self._values[key] = float(value)

    def inc(self, amount: float = 1.0, **labels: object) -> None:
        key = self._key(labels)
        with self._lock:
            if key in self._functions:
                raise MetricError(f"gauge {self.name}{dict(labels)} is read from a function; set() it instead")
            self._values[key] = self._values.get(key, 0.0) + float(amount)

    def dec(self, amount: float = 1.0, **labels: object) -> None:
        self.inc(-float(amount), **labels)


class Histogram(_Metric):
    """Latency distribution in seconds: cumulative buckets, sum and count, so p50/p95 can be derived per scrape."""

    kind = "histogram"

    def __init__(self, name: str, help: str, buckets: Sequence[float] = DEFAULT_LATENCY_BUCKETS,
                 labels: Iterable[str] = ()):
        super().__init__(name, help, labels)
        bounds = [float(b) for b in buckets if not (math.isinf(b) and b > 0)]
        if not bounds or any(math.isnan(b) for b in bounds) or any(b >= c for b, c in zip(bounds, bounds[1:])):
            raise MetricError(f"histogram {name}: buckets must be a non-empty, strictly increasing list of numbers")
        self.buckets = tuple(bounds)
        # per label key: [count per finite bucket (not cumulative)..., count above the last], sum
        self._data: dict[tuple[str, ...], tuple[list[int], list[float]]] = {}
        if not self.labels:
            self._data[()] = self._empty()

    def _reserved(self) -> set[str]:
        return _RESERVED_LABELS

    def _empty(self) -> tuple[list[int], list[float]]:
        return [0] * (len(self.buckets) + 1), [0.0]

    def observe(self, value_seconds: float, **labels: object) -> None:
        v = float(value_seconds)
        if math.isnan(v):
            raise MetricError(f"histogram {self.name}: cannot observe NaN")
        key = self._key(labels)
        slot = bisect.bisect_left(self.buckets, v)  # first bucket whose upper bound >= v ("le")
        with self._lock:
            counts, total = self._data.setdefault(key, self._empty())
            counts[slot] += 1
            total[0] += v

    def snapshot(self, **labels: object) -> tuple[list[tuple[float, int]], float, int]:
        """(cumulative (upper bound, count) incl. +Inf, sum, count) for one label set."""
        key = self._key(labels)
        with self._lock:
            counts, total = self._data.get(key, self._empty())
            counts, s = list(counts), total[0]
        cum, run = [], 0
        for bound, c in zip((*self.buckets, math.inf), counts):
            run += c
            cum.append((bound, run))
        return cum, s, run

    def _samples(self) -> list[str]:
        with self._lock:
            keys = sorted(self._data)
        lines = []
        for key in keys:
            cum, s, n = self.snapshot(**dict(zip(self.labels, key)))
            for bound, c in cum:
                le = f'le="{format_value(bound)}"'
                lines.append(f"{self.name}_bucket{_label_text(self.labels, key, le)} {c}")
            lines.append(f"{self.name}_sum{_label_text(self.labels, key)} {format_value(s)}")
            lines.append(f"{self.name}_count{_label_text(self.labels, key)} {n}")
        return lines


def _series(histogram: str) -> set[str]:
    return {f"{histogram}_{suffix}" for suffix in ("bucket", "sum", "count")}


class Registry:
    """The daemon's metrics. Declaring the same metric twice returns the first one (same kind and labels)."""

    content_type = "text/plain; version=0.0.4; charset=utf-8"

    def __init__(self) -> None:
        self._metrics: dict[str, _Metric] = {}
        self._lock = threading.Lock()

    def _get_or_add(self, cls: type, name: str, help: str, labels: Iterable[str], **kw) -> _Metric:
        metric = cls(name, help, labels=labels, **kw)
        with self._lock:
            have = self._metrics.get(name)
            if have is None:
                for other in self._metrics.values():
                    if isinstance(other, Histogram) and name in _series(other.name):
                        raise MetricError(f"metric {name} collides with histogram {other.name}'s series")
                    if cls is Histogram and other.name in _series(name):
                        raise MetricError(f"histogram {name}'s series collide with metric {other.name}")
                self._metrics[name] = metric
                return metric
        same = type(have) is cls and have.labels == metric.labels and \
            getattr(have, "buckets", None) == getattr(metric, "buckets", None)
        if not same:
            raise MetricError(f"metric {name} is already declared as a {have.kind} with labels {list(have.labels)}")
        return have

    def counter(self, name: str, help: str, labels: Iterable[str] = ()) -> Counter:
        return self._get_or_add(Counter, name, help, labels)  # type: ignore[return-value]

    def gauge(self, name: str, help: str, labels: Iterable[str] = ()) -> Gauge:
        return self._get_or_add(Gauge, name, help, labels)  # type: ignore[return-value]

    def histogram(self, name: str, help: str, buckets: Sequence[float] = DEFAULT_LATENCY_BUCKETS,
                  labels: Iterable[str] = ()) -> Histogram:
        return self._get_or_add(Histogram, name, help, labels, buckets=buckets)  # type: ignore[return-value]

    def get(self, name: str) -> _Metric | None:
        with self._lock:
            return self._metrics.get(name)

    def render(self) -> str:
        """The whole registry as Prometheus text exposition format 0.0.4 (serve with `content_type`)."""
        with self._lock:
            metrics = list(self._metrics.values())
        return "".join(m.render() for m in metrics)
