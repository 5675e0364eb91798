"""Manifests from outside: the signature is checked over the manifest's bytes before any YAML is parsed, and a
hostile manifest (deep nesting, a huge integer, anything at all) is a one-line BundleError, never a traceback."""
from __future__ import annotations

import io
import subprocess
import sys
import tarfile
from pathlib import Path

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from exporter.bundle_writer import sign_manifest
from exporter.keys import generate_keypair, load_private_key
from kiosk.bundle.archive import open_bundle, verify_directory
from kiosk.bundle.manifest import BundleError, parse_manifest
from kiosk.bundle.signature import load_trusted_keys

ROOT = Path(__file__).resolve().parents[3]
DEEP = b"[" * 2_000 + b"]" * 2_000
HOSTILE = {"deep-list": DEEP, "deep-map": b"{a: " * 2_000 + b"1" + b"}" * 2_000,
           "deep-block": "".join(" " * i + "-\n" for i in range(700)).encode() + b" " * 700 + b"1\n",
           "huge-int": b"schema_version: " + b"9" * 5000 + b"\n"}


def _archive(tmp: Path, name: str, manifest: bytes, key=None) -> Path:
    out = tmp / f"{name}.vtb"
    with tarfile.open(out, "w") as tar:
        members = {"manifest.yaml": manifest}
        if key is not None:
            members["manifest.sig"] = sign_manifest(manifest, key)
        for member, data in members.items():
            info = tarfile.TarInfo(member)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    return out


@pytest.fixture(scope="module")
def keys(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("keys")
    generate_keypair(tmp / "k", "operator")
    generate_keypair(tmp / "s", "stranger")
    (tmp / "trusted").mkdir()
    (tmp / "trusted" / "operator.pub").write_bytes((tmp / "k" / "operator.pub").read_bytes())
    return {"trusted": tmp / "trusted", "operator": load_private_key(tmp / "k" / "operator.key"),
            "stranger": load_private_key(tmp / "s" / "stranger.key")}


@pytest.mark.parametrize("kind", sorted(HOSTILE))
def test_unsigned_or_foreign_manifests_are_refused_before_parsing(tmp_path, keys, kind):
    trusted = load_trusted_keys(keys["trusted"])
    with pytest.raises(BundleError, match="not signed"):
        open_bundle(_archive(tmp_path, "unsigned", HOSTILE[kind]), trusted, workdir=tmp_path / "w")
    with pytest.raises(BundleError, match="not among the trusted keys"):
        open_bundle(_archive(tmp_path, "foreign", HOSTILE[kind], keys["stranger"]), trusted, workdir=tmp_path / "w")


@pytest.mark.parametrize("kind", sorted(HOSTILE))
def test_a_signed_hostile_manifest_is_one_line(tmp_path, keys, kind):
    trusted = load_trusted_keys(keys["trusted"])
    with pytest.raises(BundleError) as e:
        open_bundle(_archive(tmp_path, "signed", HOSTILE[kind], keys["operator"]), trusted, workdir=tmp_path / "w")
    assert "\n" not in str(e.value) and len(str(e.value)) < 300


def test_the_command_says_one_line_and_exits_2(tmp_path, keys):
    bundle = _archive(tmp_path, "deep", DEEP, keys["operator"])
    proc = subprocess.run([sys.executable, "-m", "vtkiosk", "bundle", "verify", str(bundle), "--trusted-keys",
                           str(keys["trusted"])], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert "nests" in proc.stderr


def test_verify_directory_checks_the_signature_first(tmp_path, keys):
    folder = tmp_path / "b"
    folder.mkdir()
    (folder / "manifest.yaml").write_bytes(DEEP)
    with pytest.raises(BundleError, match="not signed"):
        verify_directory(folder, load_trusted_keys(keys["trusted"]))


yaml_scalars = st.one_of(st.integers(), st.floats(allow_nan=True), st.text(max_size=20), st.booleans(), st.none())
yaml_docs = st.recursive(yaml_scalars, lambda kids: st.one_of(st.lists(kids, max_size=4),
                                                              st.dictionaries(st.text(max_size=8), kids, max_size=4)),
                         max_leaves=20)


@settings(max_examples=100, deadline=None)
@given(st.one_of(st.binary(max_size=300), yaml_docs.map(lambda d: yaml.safe_dump(d).encode()),
                 st.integers(1, 200).map(lambda n: b"a:\n" + b"".join(b"  " * i + b"- " for i in range(n)) + b"1")))
def test_any_bytes_give_a_manifest_or_a_one_line_bundle_error(data):
    try:
        parse_manifest(data)
    except BundleError as exc:
        assert "\n" not in str(exc)
