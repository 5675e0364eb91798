"""The arrows of docs/architecture.md, enforced: every import in the tree (module level or inside a function) goes
from a room to a room it may use. Parsed with `ast`, so a lazy import cannot hide a wrong arrow."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
OURS = ("kiosk", "firmware_bridge", "trainer", "exporter", "vtkiosk")

# room -> what it may import (rooms, or single modules). Mirrors the table in docs/architecture.md.
ALLOWED: dict[str, set[str]] = {
    "kiosk.contract": set(),
    "kiosk.config": set(),
    "kiosk.bundle": {"kiosk.contract"},
    "kiosk.inference": {"kiosk.contract", "kiosk.bundle"},
    "kiosk.ops": {"kiosk.contract"},
    "kiosk.service": {"kiosk.contract", "kiosk.config", "kiosk.bundle", "kiosk.inference", "kiosk.ops",
                      "kiosk.fleet.layout", "kiosk.fleet.state", "firmware_bridge"},
    "kiosk.fleet": {"kiosk.contract", "kiosk.bundle", "kiosk.ops", "kiosk.service.config"},
    "kiosk.study": {"kiosk.contract", "kiosk.config", "kiosk.bundle", "kiosk.inference", "kiosk.ops",
                    "kiosk.service", "firmware_bridge"},
    "kiosk.bench": {"kiosk.contract", "kiosk.config", "kiosk.bundle", "kiosk.inference", "kiosk.ops"},
    "firmware_bridge": set(),
    "trainer": {"kiosk.contract", "kiosk.config", "kiosk.ops.signals", "kiosk.inference.cpu"},
    "exporter": {"trainer", "kiosk.contract", "kiosk.config", "kiosk.bundle", "kiosk.inference", "kiosk.bench"},
    "vtkiosk": {"kiosk", "firmware_bridge", "trainer", "exporter"},
}
# A room's command line is its front door and may also drive the rooms its commands talk to.
FRONT_DOORS: dict[str, set[str]] = {
    "kiosk/bundle/cli.py": {"kiosk.service.config", "kiosk.ops.control", "kiosk.ops.logsetup"},
}


def room_of(module: str) -> str:
    parts = module.split(".")
    return ".".join(parts[:2]) if parts[0] == "kiosk" and len(parts) > 1 else parts[0]


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports_of(path: Path) -> list[tuple[int, str]]:
    """(line, absolute module) of every import of ours in `path`, lazy ones inside functions included."""
    here = module_name(path)
    package = here if path.name == "__init__.py" else here.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[:len(package.split(".")) - node.level + 1]
                names = [".".join(base + ([node.module] if node.module else []))]
            else:
                names = [node.module or ""]
        else:
            continue
        out += [(node.lineno, n) for n in names if n.split(".")[0] in OURS]
    return out


def allowed(path: Path, target: str) -> bool:
    src = room_of(module_name(path))
    if room_of(target) == src or target.split(".")[0] == src:
        return True
    permitted = ALLOWED[src if src in ALLOWED else src.split(".")[0]] | FRONT_DOORS.get(
        path.relative_to(ROOT).as_posix(), set())
    return any(target == p or target.startswith(p + ".") for p in permitted)


def sources() -> list[Path]:
    return sorted(p for pkg in OURS for p in (ROOT / pkg).rglob("*.py"))


def test_every_room_is_in_the_table():
    rooms = {room_of(module_name(p)) for p in sources()} - set(OURS)
    missing = sorted(r for r in rooms if r not in ALLOWED and r != "kiosk")
    assert not missing, f"new room(s) {missing}: add them to docs/architecture.md and ALLOWED here"


def test_no_module_outside_a_room_in_kiosk():
    loose = sorted(p.name for p in (ROOT / "kiosk").glob("*.py") if p.name != "__init__.py")
    assert not loose, f"kiosk/ keeps modules in role folders only; move {loose}"


def test_imports_follow_the_arrows():
    wrong = [f"{p.relative_to(ROOT)}:{line} imports {target}"
             for p in sources() for line, target in imports_of(p) if not allowed(p, target)]
    assert not wrong, "imports against docs/architecture.md:\n" + "\n".join(wrong)


# Inside kiosk/service, the daemon wires the parts; a part never reaches back into the wiring, and the parts that
# run a job (jobs, frames, bundles) never import the HTTP route table.
SERVICE_WIRING = {"kiosk.service.daemon": {"kiosk/service/daemon.py", "kiosk/service/cli.py"},
                  "kiosk.service.routes": {"kiosk/service/daemon.py", "kiosk/service/routes.py"}}


def service_allowed(path: Path, target: str) -> bool:
    """Other rooms (the study, the demo) may use the daemon whole; this only rules kiosk/service itself."""
    here = path.relative_to(ROOT).as_posix()
    users = next((v for k, v in SERVICE_WIRING.items() if target == k or target.startswith(k + ".")), None)
    return users is None or not here.startswith("kiosk/service/") or here in users


def test_the_service_parts_never_import_the_wiring():
    wrong = [f"{p.relative_to(ROOT)}:{line} imports {target}"
             for p in sources() for line, target in imports_of(p) if not service_allowed(p, target)]
    assert not wrong, "kiosk.service.daemon wires the parts; they must not import it (or the routes):\n" + \
        "\n".join(wrong)


@pytest.mark.parametrize("code, target, ok", [
    ("kiosk/service/frames.py", "kiosk.service.daemon", False),
    ("kiosk/service/bundles.py", "kiosk.service.routes", False),
    ("kiosk/service/jobs.py", "kiosk.service.daemon", False),
    ("kiosk/study/runtime.py", "kiosk.service.daemon", True),
    ("kiosk/service/cli.py", "kiosk.service.daemon", True),
    ("kiosk/service/daemon.py", "kiosk.service.routes", True),
    ("kiosk/service/routes.py", "kiosk.service.jobs", True),
])
def test_the_service_checker_tells_right_from_wrong(code, target, ok):
    assert service_allowed(ROOT / code, target) is ok


@pytest.mark.parametrize("code, target, ok", [
    ("kiosk/contract/sketch.py", "kiosk.service.daemon", False),
    ("kiosk/service/daemon.py", "trainer.loop", False),
    ("kiosk/inference/engine.py", "exporter.graphs", False),
    ("firmware_bridge/display.py", "kiosk.contract.sketch", False),
    ("trainer/loop.py", "exporter.graphs", False),
    ("trainer/loop.py", "kiosk.ops.health", False),
    ("kiosk/bundle/store.py", "kiosk.service.config", False),
    ("kiosk/bundle/cli.py", "kiosk.service.config", True),
    ("exporter/export.py", "trainer.checkpoint", True),
    ("kiosk/service/daemon.py", "firmware_bridge.display", True),
])
def test_the_checker_tells_right_from_wrong(code, target, ok):
    assert allowed(ROOT / code, target) is ok


def test_lazy_and_relative_imports_are_seen(tmp_path):
    path = ROOT / "firmware_bridge" / "cli.py"
    found = {t for _, t in imports_of(path)}
    assert "firmware_bridge.config" in found            # `from .config import ...`
    assert "firmware_bridge.emulator" in found           # `from .emulator import ...` inside a function
