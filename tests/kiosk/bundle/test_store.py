"""kiosk.bundle.store and `vtkiosk bundle install|list|activate|rollback|remove`: real signed bundles, real ORT probes,
hostile and broken input, crashes mid-install, concurrent operators, and a real daemon told over its socket."""
from __future__ import annotations

import errno
import fcntl
import json
import os
import subprocess
import sys
import tarfile
import textwrap
from pathlib import Path

import pytest

from kiosk.bundle.archive import verify_directory
from kiosk.bundle.manifest import BundleError
from kiosk.bundle.signature import load_trusted_keys
from kiosk.bundle.store import BundleStore, StoreBusyError, StoreError
from tests.kiosk.bundle_factory import base_manifest, make_bundle

ROOT = Path(__file__).resolve().parents[3]
V1, V2, V3 = "2026.11.21-1", "2026.11.22-1", "2026.11.23-1"


@pytest.fixture(scope="module")
def bundles(tmp_path_factory):
    """Three versions of one garment, another garment, all signed by the trusted key; plus hostile variants."""
    tmp = tmp_path_factory.mktemp("store-bundles")
    out = {}
    for v in (V1, V2, V3):
        out[v], trusted = make_bundle(tmp, name=f"denim-{v}.vtb", manifest=base_manifest(model_version=v))
    out["shirt"], _ = make_bundle(tmp, name="shirt.vtb", manifest=base_manifest(garment_id="linen-shirt"))
    out["unsigned"], _ = make_bundle(tmp, name="unsigned.vtb", sign=False,
                                     manifest=base_manifest(model_version="9-unsigned"))
    stranger = tmp / "stranger"
    stranger.mkdir()
    out["stranger"], _ = make_bundle(stranger, name="stranger.vtb", key_name="stranger",
                                     manifest=base_manifest(model_version="9-stranger"))
    out["poison"], _ = make_bundle(tmp, name="poison.vtb", poison=True, manifest=base_manifest(model_version="9-nan"))
    out["reserved"], _ = make_bundle(tmp, name="reserved.vtb", manifest=base_manifest(model_version="current"))
    out["v1-other"], _ = make_bundle(tmp, name="v1-other.vtb",
                                     manifest=base_manifest(model_version=V1, display_name="Denim shorts (redo)"))
    out["trusted"] = trusted
    return out


def _tampered(src: Path, dest: Path) -> Path:
    """The archive with one graph's bytes changed but the signed manifest untouched."""
    with tarfile.open(src) as tin, tarfile.open(dest, "w") as tout:
        for m in tin.getmembers():
            data = tin.extractfile(m).read() if m.isreg() else None
            if m.name.endswith("graphs/tactile.onnx"):
                data = data[:-1] + bytes([data[-1] ^ 0xFF])
            if data is not None:
                import io
                m.size = len(data)
                tout.addfile(m, io.BytesIO(data))
            else:
                tout.addfile(m)
    return dest


def _store(tmp_path, bundles, **kw) -> BundleStore:
    return BundleStore(tmp_path / "store", bundles["trusted"], **kw)


def _visible(root: Path) -> list[str]:
    """Everything in the store except the lock file and the empty work folder."""
    return sorted(str(p.relative_to(root)) for p in root.rglob("*")
                  if p.name != ".lock" and not (p.name == ".incoming" and not any(p.iterdir())))


def test_install_activate_rollback_remove_cycle(tmp_path, bundles):
    store = _store(tmp_path, bundles)
    assert store.list() == [] and store.active() == {}
    s1 = store.install(bundles[V1])
    assert (s1.garment, s1.version, s1.active, s1.previous) == ("denim-shorts", V1, False, False)
    assert s1.key_id is not None and s1.precisions == {"full": "fp32", "tactile": "fp32", "visual": "fp32"}
    assert s1.display_name == "Denim shorts" and len(s1.archive_sha256) == 64
    # what the daemon does with it: verify the stored folder against the trusted keys
    assert verify_directory(s1.path, load_trusted_keys(bundles["trusted"])).manifest.model_version == V1
    assert store.active() == {}
    assert store.activate("denim-shorts", V1).active
    assert os.readlink(store.root / "denim-shorts" / "current") == V1
    store.install(bundles[V2])
    a2 = store.activate("denim-shorts", V2)
    assert a2.active and store.links("denim-shorts") == (V2, V1)
    assert store.active()["denim-shorts"].version == V2
    assert [(s.version, s.active, s.previous) for s in store.list()] == [(V1, False, True), (V2, True, False)]
    back = store.rollback("denim-shorts")
    assert back.version == V1 and store.links("denim-shorts") == (V1, None)
    with pytest.raises(StoreError, match="no earlier version in its history"):
        store.rollback("denim-shorts")  # a second rollback goes further back, not back to V2
    assert store.activate("denim-shorts", V2).active and store.links("denim-shorts") == (V2, V1)
    with pytest.raises(StoreError, match="is the active version"):
        store.remove("denim-shorts", V2)
    store.remove("denim-shorts", V1)
    assert store.links("denim-shorts") == (V2, None)
    assert not (store.root / "denim-shorts" / V1).exists()
    with pytest.raises(StoreError, match="no earlier version in its history to roll back to \\(active: 2026.11.22-1\\)"):
        store.rollback("denim-shorts")
    assert store.activate("denim-shorts", V2).active  # already active: no change
    assert store.links("denim-shorts") == (V2, None)


def test_rollback_walks_back_through_the_history_and_says_where_it_went(tmp_path, bundles):
    store = _store(tmp_path, bundles)
    for v in (V1, V2, V3):
        store.install(bundles[v])
        store.activate("denim-shorts", v)
    assert store.history("denim-shorts") == [V1, V2, V3]
    assert store.rollback("denim-shorts").version == V2 and store.links("denim-shorts") == (V2, V1)
    assert store.rollback("denim-shorts").version == V1 and store.links("denim-shorts") == (V1, None)
    assert store.history("denim-shorts") == [V1]
    # the daemon refused a rollback: restore puts the version rolled back from on top again
    store.restore("denim-shorts", current=V2, previous=V1)
    assert store.history("denim-shorts") == [V1, V2]
    # a store written before the history existed: one step back through its previous link
    (store.root / "denim-shorts" / ".meta" / ".history").unlink()
    assert store.rollback("denim-shorts").version == V1


def test_a_history_write_that_fails_activates_nothing_and_leaves_no_temporary(tmp_path, bundles, monkeypatch):
    store = _store(tmp_path, bundles)
    store.install(bundles[V1])
    store.activate("denim-shorts", V1)
    store.install(bundles[V2])
    meta = store.root / "denim-shorts" / ".meta"
    before = sorted(p.name for p in meta.iterdir())

    def full(fd):
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr("kiosk.bundle.durable.os.fsync", full)
    with pytest.raises(OSError, match="No space left"):
        store.activate("denim-shorts", V2)
    monkeypatch.undo()
    assert sorted(p.name for p in meta.iterdir()) == before   # the old history, no temporary beside it
    assert store.history("denim-shorts") == [V1] and store.links("denim-shorts") == (V1, None)


def test_rollback_cli_names_the_version_it_went_to(tmp_path, bundles):
    store = _store(tmp_path, bundles)
    for v in (V1, V2, V3):
        store.install(bundles[v])
        store.activate("denim-shorts", v)
    from kiosk.bundle.cli import main
    import contextlib
    import io
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        rc = main(["rollback", "denim-shorts", "--store", str(store.root), "--trusted-keys", str(bundles["trusted"]),
                   "--no-reload"])
    assert rc == 0
    assert out.getvalue().strip() == f"rolled back denim-shorts to {V2} (from {V3}); history: {V1} -> {V2}"


def test_garments_are_independent(tmp_path, bundles):
    store = _store(tmp_path, bundles)
    store.install(bundles[V1], activate_if_first=True)
    store.install(bundles["shirt"], activate_if_first=True)
    store.install(bundles[V2], activate_if_first=True)  # denim already has an active version: stays inactive
    assert {g: s.version for g, s in store.active().items()} == {"denim-shorts": V1, "linen-shirt": V1}


@pytest.mark.parametrize("which, match", [
    ("unsigned", "is not signed"),
    ("stranger", "which is not among the trusted keys"),
    ("poison", "non-finite"),
    ("reserved", "cannot name a store folder"),
])
def test_bad_bundles_are_refused_and_leave_nothing(tmp_path, bundles, which, match):
    store = _store(tmp_path, bundles)
    with pytest.raises((BundleError, StoreError), match=match):
        store.install(bundles[which])
    assert _visible(store.root) == []


def test_tampered_hash_is_refused(tmp_path, bundles):
    store = _store(tmp_path, bundles)
    bad = _tampered(bundles[V1], tmp_path / "tampered.vtb")
    with pytest.raises(BundleError, match="does not match its SHA-256"):
        store.install(bad)
    assert _visible(store.root) == []


def test_unsigned_needs_explicit_permission_and_keys_are_required(tmp_path, bundles):
    with pytest.raises(BundleError, match="no trusted keys configured"):
        BundleStore(tmp_path / "s1", None).install(bundles[V1])
    dev = BundleStore(tmp_path / "s2", None, allow_unsigned=True)
    s = dev.install(bundles["unsigned"])
    assert s.key_id is None
    assert not (tmp_path / "s1" / "denim-shorts").exists()


def test_same_version_twice_is_refused(tmp_path, bundles):
    store = _store(tmp_path, bundles)
    store.install(bundles[V1])
    with pytest.raises(StoreError, match="already installed \\(the same bundle\\)"):
        store.install(bundles[V1])
    with pytest.raises(StoreError, match="already installed with different content"):
        store.install(bundles["v1-other"])
    assert [s.version for s in store.list()] == [V1]


def test_unknown_garment_or_version(tmp_path, bundles):
    store = _store(tmp_path, bundles)
    store.install(bundles[V1])
    with pytest.raises(StoreError, match="no garment 'silk' in the store .* \\(installed: denim-shorts\\)"):
        store.activate("silk", V1)
    with pytest.raises(StoreError, match="has no version '9' \\(installed: 2026.11.21-1\\)"):
        store.activate("denim-shorts", "9")
    with pytest.raises(StoreError, match="not a valid version name"):
        store.remove("denim-shorts", "../../etc")
    with pytest.raises(StoreError, match="not a valid garment name"):
        store.rollback("../x")
    with pytest.raises(StoreError, match="no such bundle"):
        store.install(tmp_path / "absent.vtb")


def test_a_bundle_damaged_on_disk_is_never_activated(tmp_path, bundles):
    store = _store(tmp_path, bundles)
    s = store.install(bundles[V1])
    graph = s.path / "graphs" / "visual.onnx"
    graph.write_bytes(graph.read_bytes() + b"\0")
    with pytest.raises(BundleError, match="does not match its SHA-256"):
        store.activate("denim-shorts", V1)
    assert store.active() == {}


def test_install_from_an_unpacked_folder(tmp_path, bundles):
    src = tmp_path / "unpacked"
    src.mkdir()
    with tarfile.open(bundles[V3]) as t:
        t.extractall(src, filter="data")
    store = _store(tmp_path, bundles)
    assert store.install(src).version == V3
    (src / "graphs" / "evil").symlink_to("/etc/passwd")
    with pytest.raises(BundleError, match="symbolic link"):
        _store(tmp_path / "again", bundles).install(src)


CRASH = textwrap.dedent("""
    import os, sys
    import kiosk.bundle.store as S
    point = sys.argv[3]
    def die(*a, **k):
        os._exit(9)  # like SIGKILL: no cleanup, no finally
    if point == "extract":
        real = S.safe_extract
        def extract(archive, dest, limits):
            real(archive, dest, limits)
            die()
        S.safe_extract = extract
    elif point == "probe":
        import kiosk.bundle.probe as P
        P.probe_bundle = die
    elif point == "between-renames":
        real_rename = os.rename
        calls = []
        def rename(a, b):
            real_rename(a, b)
            calls.append(b)
            if len(calls) == 1:
                die()
        S.os.rename = rename
    S.BundleStore(sys.argv[1], sys.argv[2]).install(sys.argv[4])
    print("finished")
""")


@pytest.mark.parametrize("point", ["extract", "probe", "between-renames"])
def test_a_crash_mid_install_leaves_no_half_bundle(tmp_path, bundles, point):
    root = tmp_path / "store"
    proc = subprocess.run([sys.executable, "-c", CRASH, str(root), str(bundles["trusted"]), point, str(bundles[V1])],
                          cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 9 and "finished" not in proc.stdout, proc.stderr
    store = BundleStore(root, bundles["trusted"])
    assert store.list() == [] and store.active() == {}
    with pytest.raises(StoreError, match="no garment|has no version"):
        store.activate("denim-shorts", V1)
    # the next operation cleans up and the same version installs fine
    assert store.install(bundles[V1]).version == V1
    assert _visible(root) == sorted(str(p.relative_to(root)) for p in root.rglob("*")
                                    if p.name != ".lock" and p.name != ".incoming")
    assert not any((root / ".incoming").iterdir())
    assert [p.name for p in (root / "denim-shorts").iterdir() if p.name != ".meta"] == [V1]


@pytest.mark.skipif(os.geteuid() != 0, reason="handing files to another user needs root")
def test_run_as_root_what_it_creates_belongs_to_the_stores_owner(tmp_path, bundles):
    import pwd

    nobody = pwd.getpwnam("nobody")
    root = tmp_path / "store"
    root.mkdir()
    os.chown(root, nobody.pw_uid, nobody.pw_gid)
    store = BundleStore(root, bundles["trusted"])
    store.install(bundles[V1])
    store.activate("denim-shorts", V1)
    store.install(bundles[V2])
    store.activate("denim-shorts", V2)
    owners = {(p.lstat().st_uid, p.lstat().st_gid) for p in root.rglob("*")}
    assert owners == {(nobody.pw_uid, nobody.pw_gid)}, sorted(str(p) for p in root.rglob("*")
                                                             if p.lstat().st_uid != nobody.pw_uid)


def test_lock_held_elsewhere_is_a_clear_busy_error(tmp_path, bundles):
    store = BundleStore(tmp_path / "store", bundles["trusted"], lock_timeout_s=0.3)
    store.install(bundles[V1])
    fd = os.open(store.root / ".lock", os.O_RDWR)
    fcntl.flock(fd, fcntl.LOCK_EX)
    try:
        with pytest.raises(StoreBusyError, match="another bundle operation holds"):
            store.activate("denim-shorts", V1)
    finally:
        os.close(fd)
    assert store.activate("denim-shorts", V1).active


RACE = textwrap.dedent("""
    import sys
    from kiosk.bundle.store import BundleStore
    store = BundleStore(sys.argv[1], sys.argv[2])
    for i in range(int(sys.argv[4])):
        store.activate("denim-shorts", sys.argv[3].split(",")[i % 3], allow_downgrade=True)
        cur, prev = store.links("denim-shorts")
        assert cur is not None and cur != prev, (cur, prev)
""")


@pytest.mark.slow
def test_concurrent_activations_keep_the_store_consistent(tmp_path, bundles):
    store = _store(tmp_path, bundles)
    for v in (V1, V2, V3):
        store.install(bundles[v])
    orders = [f"{V1},{V2},{V3}", f"{V3},{V1},{V2}", f"{V2},{V3},{V1}"]
    procs = [subprocess.Popen([sys.executable, "-c", RACE, str(store.root), str(bundles["trusted"]), o, "12"],
                              cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for o in orders]
    seen = set()
    while any(p.poll() is None for p in procs):  # a reader never sees a missing or dangling 'current'
        cur = store.active().get("denim-shorts")
        if cur is not None:
            seen.add(cur.version)
            assert cur.path.is_dir()
    for p in procs:
        out, err = p.communicate(timeout=120)
        assert p.returncode == 0, err
    cur, prev = store.links("denim-shorts")
    assert {cur, prev} <= {V1, V2, V3} and cur != prev
    assert not [p for p in (store.root / "denim-shorts").iterdir() if p.name.startswith(".current.")]
    assert seen


# -- the command line ----------------------------------------------------------------------------------------------

def cli(*args, check=True) -> subprocess.CompletedProcess:
    proc = subprocess.run([sys.executable, "-m", "vtkiosk", "bundle", *map(str, args)], cwd=ROOT,
                          capture_output=True, text=True, timeout=180)
    if check:
        assert proc.returncode == 0, proc.stdout + proc.stderr
    return proc


def test_cli_without_a_daemon(tmp_path, bundles):
    root, keys, sock = tmp_path / "store", bundles["trusted"], tmp_path / "control.sock"
    common = ["--store", root, "--trusted-keys", keys, "--control-socket", sock]
    out = cli("install", bundles[V1], bundles[V2], *common).stdout
    assert f"installed denim-shorts {V1} (signed by " in out and "fp32) into" in out
    refused = cli("activate", "denim-shorts", V1, *common, check=False)
    assert refused.returncode == 2 and refused.stdout == "" and refused.stderr.count("\n") == 1
    assert f"refusing to activate denim-shorts {V1}: it is older than the installed {V2}" in refused.stderr
    out = cli("activate", "denim-shorts", V1, "--allow-downgrade", *common).stdout
    assert f"activated denim-shorts {V1}" in out
    assert f"no kiosk daemon is running (nothing listens on {sock}); it will serve denim-shorts {V1}" in out
    cli("activate", "denim-shorts", V2, *common)
    lines = cli("list", *common).stdout.splitlines()
    assert lines[0].split() == ["GARMENT", "VERSION", "STATE", "SIGNED", "BY", "PRECISION", "INSTALLED"]
    assert lines[1].split()[:3] == ["denim-shorts", V1, "previous"] and lines[2].split()[:3] == [
        "denim-shorts", V2, "active"]
    assert lines[1].split()[4] == "fp32"
    out = cli("rollback", "denim-shorts", *common).stdout
    assert f"rolled back denim-shorts to {V1} (from {V2}); history: {V1}" in out
    listing = json.loads(cli("list", "--json", *common).stdout)
    assert [(e["version"], e["active"], e["previous"]) for e in listing] == [(V1, True, False), (V2, False, False)]
    bad = cli("remove", "denim-shorts", V1, *common, check=False)
    assert bad.returncode == 2 and "is the active version" in bad.stderr and "Traceback" not in bad.stderr
    assert "removed denim-shorts" in cli("remove", "denim-shorts", V2, *common).stdout
    bad = cli("install", bundles["unsigned"], *common, check=False)
    assert bad.returncode == 2 and "is not signed" in bad.stderr
    bad = cli("activate", "silk", "1", *common, check=False)
    assert bad.returncode == 2 and "no garment 'silk'" in bad.stderr
    (tmp_path / "empty").mkdir()
    assert "no bundles installed" in cli("list", "--store", tmp_path / "empty").stdout
    bad = cli("list", "--store", tmp_path / "typo", check=False)
    assert bad.returncode == 2 and "no bundle store at" in bad.stderr


def test_cli_reads_store_keys_and_socket_from_the_kiosk_config(tmp_path, bundles):
    cfg = tmp_path / "kiosk.yaml"
    cfg.write_text(f"store: {{root: {tmp_path / 'cfgstore'}, trusted_keys: {bundles['trusted']}}}\n"
                   f"control: {{socket: {tmp_path / 'c.sock'}}}\n")
    out = cli("install", "--activate", bundles[V1], "--config", cfg).stdout
    assert f"nothing listens on {tmp_path / 'c.sock'}" in out
    assert BundleStore(tmp_path / "cfgstore", None).active()["denim-shorts"].version == V1
    # inspect/verify keep working
    assert "verified    ok" in cli("verify", bundles[V1], "--trusted-keys", bundles["trusted"]).stdout


@pytest.mark.slow
def test_cli_tells_a_running_daemon_which_swaps_or_refuses(tmp_path, bundles):
    """A real daemon serving the store: activate makes it swap; a version it refuses is switched back."""
    from tests.kiosk.daemon_fixtures import start_daemon

    root, keys, sock = tmp_path / "store", bundles["trusted"], tmp_path / "control.sock"
    common = ["--store", root, "--trusted-keys", keys, "--control-socket", sock]
    cli("install", "--activate", bundles[V1], *common)
    cli("install", bundles[V2], bundles["shirt"], *common)
    d = start_daemon([], keys, store={"root": str(root)}, control={"socket": str(sock)})
    try:
        served = lambda: {g: b["model_version"] for g, b in d.status()["bundles"].items()}  # noqa: E731
        assert served() == {"denim-shorts": V1}  # linen-shirt is installed but not active
        out = cli("activate", "denim-shorts", V2, *common).stdout
        assert "daemon reloaded: serving denim-shorts" in out and V2 in out
        assert served() == {"denim-shorts": V2}
        out = cli("rollback", "denim-shorts", *common).stdout
        assert served() == {"denim-shorts": V1} and "daemon reloaded" in out
        out = cli("activate", "linen-shirt", V1, *common).stdout
        assert served() == {"denim-shorts": V1, "linen-shirt": V1}
        # a version damaged on disk after install
        g = root / "denim-shorts" / V2 / "graphs" / "full.onnx"
        os.chmod(g, 0o644)
        g.write_bytes(g.read_bytes()[:-1] + b"\0")
        proc = cli("activate", "denim-shorts", V2, *common, check=False)
        # the store's own re-verification refuses it before the daemon is even asked
        assert proc.returncode == 2 and "does not match its SHA-256" in proc.stderr
        assert BundleStore(root, keys).links("denim-shorts") == (V1, None)
    finally:
        d.stop()


@pytest.mark.slow
def test_a_version_the_daemon_refuses_is_switched_back(tmp_path, bundles):
    """The daemon probes a new version within its latency budget; with an impossible budget it keeps the old one
    and the CLI restores the store and fails with the daemon's reason."""
    from tests.kiosk.daemon_fixtures import start_daemon

    root, keys, sock = tmp_path / "store", bundles["trusted"], tmp_path / "control.sock"
    common = ["--store", root, "--trusted-keys", keys, "--control-socket", sock]
    cli("install", "--activate", bundles[V1], *common)
    cli("install", bundles[V2], *common)
    d = start_daemon([], keys, store={"root": str(root)}, control={"socket": str(sock)},
                     inference={"latency_budget_ms": 0.001})
    try:
        proc = cli("activate", "denim-shorts", V2, *common, check=False)
        assert proc.returncode == 1, proc.stdout + proc.stderr
        assert "the daemon refused denim-shorts" in proc.stderr and "latency budget" in proc.stderr
        assert "store switched back" in proc.stderr
        assert BundleStore(root, keys).links("denim-shorts") == (V1, None)
        assert {g: b["model_version"] for g, b in d.status()["bundles"].items()} == {"denim-shorts": V1}
    finally:
        d.stop()
