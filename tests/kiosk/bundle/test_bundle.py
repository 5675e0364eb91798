"""Bundles: writer -> reader round trip, signature and hash checks, probing, and hostile archives."""
import dataclasses
import gzip
import io
import subprocess
import sys
import tarfile
from pathlib import Path

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from kiosk.bundle.archive import ArchiveLimits, open_bundle, safe_extract
from kiosk.bundle.manifest import BundleError, dump_manifest, manifest_to_dict, parse_manifest
from kiosk.bundle.probe import probe_bundle
from kiosk.bundle.signature import load_trusted_keys
from tests.kiosk.bundle_factory import base_manifest, make_bundle


@pytest.fixture(scope="module")
def signed(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("bundle")
    path, trusted = make_bundle(tmp)
    return path, load_trusted_keys(trusted), tmp


def test_round_trip_and_probe(signed, tmp_path):
    path, trusted, _ = signed
    b = open_bundle(path, trusted, workdir=tmp_path)
    assert b.manifest == dataclasses.replace(base_manifest(), files=b.manifest.files)
    assert set(b.manifest.files) == {"assets/sketch.png", "assets/mask.png", "assets/visual.png",
                                     "graphs/full.onnx", "graphs/tactile.onnx", "graphs/visual.onnx"}
    assert b.key_id is not None and b.root.parent == tmp_path
    assert b.asset("mask").dtype == bool and b.asset("visual").shape == (240, 320, 3)
    results = probe_bundle(b)
    assert [r.graph for r in results] == ["full", "tactile", "visual"]
    assert results[0].size == (256, 256)


def test_manifest_dump_parse_round_trip():
    m = base_manifest(files={"graphs/full.onnx": "a" * 64, "graphs/tactile.onnx": "b" * 64,
                             "graphs/visual.onnx": "c" * 64, "assets/sketch.png": "d" * 64,
                             "assets/mask.png": "e" * 64, "assets/visual.png": "f" * 64})
    assert parse_manifest(dump_manifest(m)) == m


def _rewrite_member(src: Path, dst: Path, name: str, data: bytes | None) -> None:
    """Copy a bundle tar, replacing (or with data None, dropping) one member."""
    with tarfile.open(src) as tin, tarfile.open(dst, "w") as tout:
        for m in tin.getmembers():
            if m.name == name:
                if data is None:
                    continue
                info = tarfile.TarInfo(name)
                info.size = len(data)
                tout.addfile(info, io.BytesIO(data))
            else:
                tout.addfile(m, tin.extractfile(m))


def _member(path: Path, name: str) -> bytes:
    with tarfile.open(path) as t:
        return t.extractfile(name).read()


def _assert_rejected(path, trusted, tmp_path, match, **kw):
    work = tmp_path / "work"
    with pytest.raises(BundleError, match=match):
        open_bundle(path, trusted, workdir=work, **kw)
    assert not any(work.iterdir()), "a rejected bundle must leave nothing behind"


def test_tampered_graph_fails_hash(signed, tmp_path):
    path, trusted, _ = signed
    bad = tmp_path / "bad.vtb"
    _rewrite_member(path, bad, "graphs/tactile.onnx", _member(path, "graphs/tactile.onnx") + b"\0")
    _assert_rejected(bad, trusted, tmp_path, "graphs/tactile.onnx does not match its SHA-256")


def test_tampered_manifest_fails_signature(signed, tmp_path):
    path, trusted, _ = signed
    text = _member(path, "manifest.yaml").replace(b"friction_scale: 0.05", b"friction_scale: 0.5")
    bad = tmp_path / "bad.vtb"
    _rewrite_member(path, bad, "manifest.yaml", text)
    _assert_rejected(bad, trusted, tmp_path, "does not match the manifest")


def test_untrusted_key_and_unsigned(signed, tmp_path):
    path, _, tmp = signed
    other, other_trusted = make_bundle(tmp_path, key_name="stranger")
    _assert_rejected(path, load_trusted_keys(other_trusted), tmp_path, "not among the trusted keys")
    unsigned, trusted = make_bundle(tmp_path, name="unsigned.vtb", sign=False)
    _assert_rejected(unsigned, load_trusted_keys(trusted), tmp_path, "is not signed")
    _assert_rejected(unsigned, None, tmp_path, "no trusted keys configured")
    assert open_bundle(unsigned, None, workdir=tmp_path / "ok", allow_unsigned=True).key_id is None


def test_garbage_signature(signed, tmp_path):
    path, trusted, _ = signed
    for junk, match in ((b"hello", "not a vtkiosk-signature-v1"), (b"\xff\xfe", "not ASCII"),
                        (b"vtkiosk-signature-v1\nkey-id: 0123456789abcdef\ned25519: !!!\n", "base64")):
        bad = tmp_path / "bad.vtb"
        _rewrite_member(path, bad, "manifest.sig", junk)
        _assert_rejected(bad, trusted, tmp_path, match)


def test_missing_and_extra_files(signed, tmp_path):
    path, trusted, _ = signed
    bad = tmp_path / "missing.vtb"
    _rewrite_member(path, bad, "graphs/visual.onnx", None)
    _assert_rejected(bad, trusted, tmp_path, "missing file")
    extra = tmp_path / "extra.vtb"
    with tarfile.open(path) as tin, tarfile.open(extra, "w") as tout:
        for m in tin.getmembers():
            tout.addfile(m, tin.extractfile(m))
        info = tarfile.TarInfo("graphs/evil.onnx")
        info.size = 3
        tout.addfile(info, io.BytesIO(b"abc"))
    _assert_rejected(extra, trusted, tmp_path, "does not list")
    nomanifest = tmp_path / "nomanifest.vtb"
    _rewrite_member(path, nomanifest, "manifest.yaml", None)
    _assert_rejected(nomanifest, trusted, tmp_path, "no manifest.yaml")


def _tar_with(tmp_path: Path, build) -> Path:
    p = tmp_path / "hostile.vtb"
    with tarfile.open(p, "w") as t:
        build(t)
    return p


def _file(t, name, data=b"x"):
    info = tarfile.TarInfo(name)
    info.size = len(data)
    t.addfile(info, io.BytesIO(data))


@pytest.mark.parametrize("build, match", [
    (lambda t: _file(t, "../evil.txt"), "leave the bundle folder"),
    (lambda t: _file(t, "graphs/../../evil.txt"), "leave the bundle folder"),
    (lambda t: _file(t, "/etc/evil.txt"), "absolute"),
    (lambda t: _file(t, "a\\b"), "absolute or malformed"),
    (lambda t: _file(t, "weird name.txt"), "characters outside"),
    (lambda t: (_file(t, "a.txt"), _file(t, "a.txt")), "appears twice"),
    (lambda t: (_file(t, "a.txt"), _file(t, "./a.txt")), "appears twice"),
])
def test_hostile_names(tmp_path, build, match):
    p = _tar_with(tmp_path, build)
    _assert_rejected(p, None, tmp_path, match, allow_unsigned=True)
    assert not (tmp_path / "evil.txt").exists() and not (tmp_path.parent / "evil.txt").exists()


@pytest.mark.parametrize("kind", [tarfile.SYMTYPE, tarfile.LNKTYPE, tarfile.FIFOTYPE, tarfile.CHRTYPE])
def test_links_and_special_files(tmp_path, kind):
    def build(t):
        info = tarfile.TarInfo("manifest.yaml")
        info.type = kind
        info.linkname = "/etc/passwd"
        t.addfile(info)
    _assert_rejected(_tar_with(tmp_path, build), None, tmp_path, "only regular files", allow_unsigned=True)


def test_decompression_bomb(tmp_path):
    raw = io.BytesIO()
    with tarfile.open(fileobj=raw, mode="w") as t:
        _file(t, "zeros.bin", bytes(8 << 20))
    p = tmp_path / "bomb.vtb"
    p.write_bytes(gzip.compress(raw.getvalue(), 9))
    assert p.stat().st_size < 100_000
    _assert_rejected(p, None, tmp_path, "decompression bomb", allow_unsigned=True)


def test_oversized_file_and_too_many_members(tmp_path):
    p = _tar_with(tmp_path, lambda t: _file(t, "big.bin", bytes(4096)))
    with pytest.raises(BundleError, match="the limit is 1024"):
        safe_extract(p, tmp_path / "x", ArchiveLimits(max_file_bytes=1024))
    p = _tar_with(tmp_path, lambda t: [_file(t, f"f{i}.txt") for i in range(10)])
    with pytest.raises(BundleError, match="more than 5 members"):
        safe_extract(p, tmp_path / "y", ArchiveLimits(max_members=5))


def test_not_an_archive(tmp_path):
    p = tmp_path / "junk.vtb"
    p.write_bytes(b"this is not a tar file at all" * 100)
    _assert_rejected(p, None, tmp_path, "not a readable bundle archive", allow_unsigned=True)
    _assert_rejected(tmp_path / "absent.vtb", None, tmp_path, "no such bundle", allow_unsigned=True)


def _manifest_doc():
    m = base_manifest(files={"graphs/full.onnx": "a" * 64, "graphs/tactile.onnx": "b" * 64,
                             "graphs/visual.onnx": "c" * 64, "assets/sketch.png": "d" * 64,
                             "assets/mask.png": "e" * 64, "assets/visual.png": "f" * 64})
    return manifest_to_dict(m)


@pytest.mark.parametrize("mutate, match", [
    (lambda d: d.update(schema_version=3), "schema version 3 is not supported"),
    (lambda d: d.update(schema_version="1"), "schema_version must be an integer"),
    (lambda d: d.update(surprise=1), "unknown key"),
    (lambda d: d["haptics"].update(friction_scale=0), "must be positive"),
    (lambda d: d["haptics"].update(friction_scale=".nan"), "must be a number"),
    (lambda d: d["haptics"].update(friction_scale=True), "must be a number"),
    (lambda d: d["garment"].update(id="Bad Id!"), "invalid form"),
    (lambda d: d["graphs"]["full"].update(outputs=["visual"]), "outputs must be"),
    (lambda d: d["graphs"]["full"].update(precision="int4"), "precision must be one of"),
    (lambda d: d["graphs"]["full"].update(sizes=[[0, 5]]), "width, height"),
    (lambda d: d["graphs"].update(weird={}), "unknown graph kind"),
    (lambda d: d["files"].pop("graphs/full.onnx"), "not listed in files"),
    (lambda d: d["files"].update({"x.bin": "nothex"}), "SHA-256"),
    (lambda d: d["files"].update({"../x": "a" * 64}), "invalid path"),
    (lambda d: d["metrics"].update(psnr="high"), "must be a number"),
    (lambda d: d["haptics"].update(normalization="minmax"), "normalization must be one of"),
    (lambda d: d["haptics"].update(normalization="perceptual"), "constants are missing"),
    (lambda d: d["haptics"].update(constants={"gz_low": 1.0}), "takes no constants"),
    (lambda d: d["haptics"].update(constants={"gz_low": "low"}), "must be a number"),
    (lambda d: d["haptics"].update(pixel_pitch_mm=0), "must be positive"),
])
def test_manifest_schema_errors(mutate, match):
    doc = _manifest_doc()
    mutate(doc)
    with pytest.raises(BundleError, match=match):
        parse_manifest(yaml.safe_dump(doc).encode())


@pytest.mark.parametrize("text, match", [
    (b"a: &x 1\nb: *x\n", "anchor"),
    (b"a: !!python/object:os.system {}\n", "tag"),
    (b"a: !custom 1\n", "tag"),
    (b"- 1\n- 2\n", "top level must be a mapping"),
    (b"a: [unclosed\n", "not valid YAML"),
    (b"\xff\xfe\x00", "not UTF-8"),
    (b"x" * ((1 << 20) + 1), "the limit is"),
])
def test_manifest_yaml_hostile(text, match):
    with pytest.raises(BundleError, match=match):
        parse_manifest(text)


def _with_raw(key: str, raw: str) -> bytes:
    """A valid manifest's YAML with the line of top-level or nested `key` replaced by `key: raw`, verbatim."""
    lines = yaml.safe_dump(_manifest_doc(), sort_keys=False).splitlines()
    i = next(i for i, line in enumerate(lines) if line.strip().startswith(f"{key}:"))
    indent = lines[i][:len(lines[i]) - len(lines[i].lstrip())]
    j = i + 1
    while j < len(lines) and len(lines[j]) - len(lines[j].lstrip()) > len(indent):
        j += 1  # drop the old value's nested lines
    return "\n".join(lines[:i] + [f"{indent}{key}: {raw}"] + lines[j:]).encode() + b"\n"


@pytest.mark.parametrize("key, raw, match", [
    ("created_at", "2024-05-01T10:00:00Z", "created_at must be a non-empty string"),   # implicit timestamp
    ("display_name", "!!binary aGVsbG8=", "display_name must be a non-empty string"),  # bytes
    ("graphs", "[full, tactile]", "graphs must be a mapping"),
    ("assets", "!!set {sketch, mask}", "assets must be a mapping"),
    ("metrics", "{1: 2.0}", "keys must be strings"),
    ("metrics", "{psnr: [30, 31]}", "must be a number"),
    ("friction_scale", "0x10", None),                                                # YAML 1.1 int: accepted
    ("panel", "{size: [1280.5, 800]}", "width, height"),
    ("provenance", "{host: 3}", "provenance must map strings to strings"),
    ("schema_version", "1.0", "schema_version must be an integer"),
])
def test_manifest_yaml_unexpected_types(key, raw, match):
    data = _with_raw(key, raw)
    if match is None:
        assert parse_manifest(data).friction_scale == 16.0
        return
    with pytest.raises(BundleError, match=match):
        parse_manifest(data)


def test_manifest_alias_bomb_refused_before_expansion():
    laughs = b"a: &a [x, x, x, x, x, x, x, x, x]\n" + b"".join(
        b"%c: &%c [*%c, *%c, *%c, *%c, *%c, *%c, *%c, *%c, *%c]\n" % ((c, c) + (c - 1,) * 9)
        for c in range(ord("b"), ord("j")))
    with pytest.raises(BundleError, match="anchor"):
        parse_manifest(laughs)


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=400))
def test_manifest_parser_fuzz(data):
    try:
        parse_manifest(data)
    except BundleError:
        pass


@settings(max_examples=60, deadline=None)
@given(st.binary(min_size=0, max_size=2048))
def test_archive_fuzz(tmp_path_factory, data):
    tmp = tmp_path_factory.mktemp("fuzz")
    p = tmp / "f.vtb"
    p.write_bytes(data)
    try:
        open_bundle(p, None, workdir=tmp / "w", allow_unsigned=True)
    except BundleError:
        pass


def test_probe_rejects_non_finite_graph(tmp_path):
    path, trusted = make_bundle(tmp_path, poison=True)
    b = open_bundle(path, load_trusted_keys(trusted), workdir=tmp_path / "w")
    with pytest.raises(BundleError, match="non-finite"):
        probe_bundle(b)


def test_cli_verify_and_inspect(signed):
    path, _, tmp = signed
    run = lambda *a: subprocess.run([sys.executable, "-m", "vtkiosk", "bundle", *map(str, a)],  # noqa: E731
                                    capture_output=True, text=True, timeout=120)
    ok = run("verify", path, "--trusted-keys", tmp / "trusted")
    assert ok.returncode == 0, ok.stderr
    assert "verified    ok" in ok.stdout and "probe       tactile" in ok.stdout
    insp = run("inspect", path)
    assert insp.returncode == 0 and "denim-shorts" in insp.stdout and "NOT CHECKED" in insp.stdout
    bad = run("verify", path)
    assert bad.returncode == 2 and "no trusted keys configured" in bad.stderr
    assert len(bad.stderr.strip().splitlines()) == 1


def test_cli_keys_generate(tmp_path):
    run = lambda *a: subprocess.run([sys.executable, "-m", "vtkiosk", "keys", *map(str, a)],  # noqa: E731
                                    capture_output=True, text=True, timeout=60)
    proc = run("generate", "--out", tmp_path, "--name", "op")
    assert proc.returncode == 0 and "key id:" in proc.stdout
    assert (tmp_path / "op.key").stat().st_mode & 0o077 == 0
    again = run("generate", "--out", tmp_path, "--name", "op")
    assert again.returncode == 2 and "refusing to overwrite" in again.stderr


def test_private_key_permissions_checked(tmp_path):
    from exporter.keys import generate_keypair, load_private_key
    priv, _ = generate_keypair(tmp_path, "k")
    priv.chmod(0o644)
    with pytest.raises(BundleError, match="chmod 600"):
        load_private_key(priv)


def test_writer_is_deterministic(tmp_path):
    a, _ = make_bundle(tmp_path, name="a.vtb")
    b, _ = make_bundle(tmp_path, name="b.vtb")
    # Same sources and key give byte-identical archives (fixed mtimes, sorted members, deterministic Ed25519).
    assert a.read_bytes() == b.read_bytes()


def test_old_bundles_load_with_their_mapping_and_keep_their_bytes():
    """A manifest written before mappings had constants: same mapping, no constants, and the canonical dump (what
    is hashed and signed) is byte-identical to the old one."""
    doc = _manifest_doc()
    assert "constants" not in doc["haptics"]
    m = parse_manifest(yaml.safe_dump(doc, sort_keys=False).encode())
    assert m.friction_normalization == "calibrated" and m.friction_constants == {}
    assert "constants" not in manifest_to_dict(m)["haptics"]


def test_perceptual_manifest_round_trips_its_constants():
    from kiosk.contract.haptics import PERCEPTUAL_DEFAULTS

    consts = {**PERCEPTUAL_DEFAULTS, "gz_low": 0.002, "gz_high": 0.01}
    m = base_manifest(friction_normalization="perceptual", friction_constants=consts,
                      files={"graphs/full.onnx": "a" * 64, "graphs/tactile.onnx": "b" * 64,
                             "graphs/visual.onnx": "c" * 64, "assets/sketch.png": "d" * 64,
                             "assets/mask.png": "e" * 64, "assets/visual.png": "f" * 64})
    back = parse_manifest(dump_manifest(m))
    assert back == m and back.friction_constants["gz_high"] == 0.01
