"""Library chatter (torch.onnx, onnxruntime's quantiser, onnx) goes to a log file, not the operator's terminal.

The export prints one progress line per stage itself. Everything else the libraries write (Python warnings, the
root logger, and C++ output on file descriptors 1 and 2) is sent to the log, so a failure can still be diagnosed.
"""
from __future__ import annotations

import contextlib
import logging
import os
import sys
import warnings
from pathlib import Path


@contextlib.contextmanager
def chatter_to(log_path: Path):
    """Within the block, fds 1/2, warnings and logging go to `log_path`; yields a `say(line)` to the real stdout."""
    log_path = Path(log_path)
    log_path.parent.mkdir(parents=True, exist_ok=True)
    sys.stdout.flush()
    sys.stderr.flush()
    saved_out, saved_err = os.dup(1), os.dup(2)
    real_out = os.fdopen(os.dup(saved_out), "w", buffering=1)
    log = open(log_path, "a", buffering=1)
    root = logging.getLogger()
    saved_handlers, saved_level = root.handlers[:], root.level
    handler = logging.StreamHandler(log)
    handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
    try:
        os.dup2(log.fileno(), 1)
        os.dup2(log.fileno(), 2)
        root.handlers = [handler]
        root.setLevel(logging.INFO)
        logging.captureWarnings(True)
        with warnings.catch_warnings():
            warnings.simplefilter("default")

            def say(line: str) -> None:
                real_out.write(line + "\n")
                log.write(line + "\n")

            yield say
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        logging.captureWarnings(False)
        root.handlers, root.level = saved_handlers, saved_level
        os.dup2(saved_out, 1)
        os.dup2(saved_err, 2)
        os.close(saved_out)
        os.close(saved_err)
        real_out.close()
        log.close()
