"""One error hierarchy per package: trainer and exporter errors do not derive from the kiosk's, and the dispatcher
turns any of them into one line (it keys on `user_facing`, so no shared root is needed)."""
from __future__ import annotations

import pytest

from exporter.bench.sources import BenchError
from exporter.errors import ExportError
from firmware_bridge.errors import BridgeError
from kiosk.contract.errors import KioskError
from trainer.augment import CropError
from trainer.checkpoint import CheckpointError
from trainer.config import ConfigError as TrainerConfigError
from trainer.data.touchclothing import DatasetError
from trainer.errors import TrainerError
from trainer.methods import UnknownMethod
from vtkiosk.cli import is_user_facing

ROOTS = (KioskError, BridgeError, TrainerError, ExportError)


@pytest.mark.parametrize("error, root", [
    (TrainerConfigError, TrainerError), (UnknownMethod, TrainerError), (CheckpointError, TrainerError),
    (DatasetError, TrainerError), (CropError, TrainerError), (ExportError, ExportError), (BenchError, ExportError),
])
def test_each_error_belongs_to_its_own_package_only(error, root):
    assert [r for r in ROOTS if issubclass(error, r)] == [root]
    assert is_user_facing(error("x"))


def test_roots_are_unrelated():
    for a in ROOTS:
        assert [b for b in ROOTS if issubclass(a, b)] == [a]


def test_dispatcher_prints_a_trainer_error_as_one_line(tmp_path, capsys):
    from vtkiosk.cli import main

    assert main(["train", "--data", str(tmp_path), "--preset", "no-such-preset", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no preset 'no-such-preset'" in err
