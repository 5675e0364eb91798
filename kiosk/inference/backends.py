"""Inference engines behind one small interface: open a bundle's ONNX graph, run it on named feeds.

ONNX Runtime is always there; OpenVINO is an optional extra (`pip install vtkiosk[openvino]`) that reads the same
ONNX files, so a bundle carries no engine-specific graph. The kiosk picks one by `inference.engine.type`; `auto`
times the installed engines on the bundle at activation (see `kiosk.inference.autoselect`).
"""
from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import replace
from pathlib import Path
from typing import Protocol

import numpy as np
import onnxruntime as ort

from kiosk.contract.errors import KioskError
from kiosk.inference.sessions import SessionSettings

ENGINES = ("onnxruntime", "openvino")


class EngineUnavailable(KioskError):
    """The configured engine is not installed on this kiosk."""


class Runner(Protocol):
    """One loaded graph. `run` returns the named outputs in order, as float32 arrays the caller may keep."""

    def run(self, outputs: list[str], feeds: dict[str, np.ndarray]) -> list[np.ndarray]: ...


class OrtRunner:
    def __init__(self, path: Path, settings: SessionSettings, providers: list[str]):
        self._sess = ort.InferenceSession(str(path), settings.ort_options(), providers=providers)
        self._options = ort.RunOptions()
        self._options.log_severity_level = 3

    def run(self, outputs: list[str], feeds: dict[str, np.ndarray]) -> list[np.ndarray]:
        return self._sess.run(outputs, feeds, self._options)


class OpenVinoRunner:
    """OpenVINO, compiled once per input shape: the CPU plugin runs a static-shape model several times faster than
    the same model with dynamic H and W, and a kiosk feeds only its few grid sizes (at most `MAX_SHAPES` kept).
    The infer request reuses its output buffers, so outputs are copied out under the lock."""

    MAX_SHAPES = 8

    def __init__(self, path: Path, settings: SessionSettings | int):
        self._ov = _openvino()
        self._core = self._ov.Core()
        self._path = str(path)
        self._settings = settings if isinstance(settings, SessionSettings) else SessionSettings(threads=settings)
        self._model = self._core.read_model(self._path)
        self._compiled: OrderedDict[tuple, tuple] = OrderedDict()
        self._lock = threading.Lock()

    def _request(self, feeds: dict[str, np.ndarray]):
        key = tuple(sorted((k, v.shape) for k, v in feeds.items()))
        hit = self._compiled.get(key)
        if hit is None:
            model = self._model.clone()
            model.reshape({k: list(v.shape) for k, v in feeds.items()})
            compiled = self._core.compile_model(model, "CPU", self._settings.openvino_config())
            hit = (compiled, compiled.create_infer_request())
            self._compiled[key] = hit
            while len(self._compiled) > self.MAX_SHAPES:
                self._compiled.popitem(last=False)
        self._compiled.move_to_end(key)
        return hit

    def run(self, outputs: list[str], feeds: dict[str, np.ndarray]) -> list[np.ndarray]:
        with self._lock:
            compiled, request = self._request(feeds)
            res = request.infer(feeds)
            return [np.array(res[compiled.output(name)], dtype=np.float32, copy=True) for name in outputs]


def _openvino():
    try:
        import openvino
    except ImportError as exc:
        raise EngineUnavailable("inference engine 'openvino' is not installed (pip install 'vtkiosk[openvino]')") \
            from exc
    return openvino


def available() -> tuple[str, ...]:
    """The engines this kiosk can run now."""
    try:
        _openvino()
    except EngineUnavailable:
        return ENGINES[:1]
    return ENGINES


def open_graph(engine: str, path: Path, *, threads: int, providers: list[str] | None = None,
               settings: SessionSettings | None = None) -> Runner:
    """Load one ONNX graph in the named engine with `settings` (the engine's arena, streams ...) and `threads` (the
    caller's lane decides those). Raises EngineUnavailable, or the engine's own error on a bad graph."""
    settings = replace(settings or SessionSettings(), threads=threads)
    if engine == "onnxruntime":
        return OrtRunner(path, settings, providers or ["CPUExecutionProvider"])
    if engine == "openvino":
        return OpenVinoRunner(path, settings)
    raise EngineUnavailable(f"unknown inference engine {engine!r} (one of {', '.join(ENGINES)})")
