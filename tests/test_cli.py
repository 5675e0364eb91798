"""The `vtkiosk` dispatcher: help, unknown commands, one-line errors."""
import subprocess
import sys

from vtkiosk.cli import COMMANDS, is_user_facing, main


def test_help_lists_every_command(capsys):
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    for command in COMMANDS:
        assert command in out


def test_unknown_command(capsys):
    assert main(["frobnicate"]) == 2
    assert "unknown command 'frobnicate'" in capsys.readouterr().err


def test_user_facing_classification():
    from kiosk.contract.errors import InputError
    assert is_user_facing(InputError("x"))
    assert is_user_facing(FileNotFoundError("x"))
    assert not is_user_facing(KeyError("x"))


def test_entry_point_runs_as_module():
    proc = subprocess.run([sys.executable, "-m", "vtkiosk", "--help"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0 and "usage: vtkiosk" in proc.stdout
