"""The study's bundles: one per (condition, garment), verified like any kiosk bundle, checked for what a trial needs.

A trial shows the reference condition's ground-truth visual on both halves and renders each condition's tactile
output under its half, so every bundle must ship the reference assets (visual, sketch, mask) and a graph that
computes tactile, and all conditions of one garment must carry the *same* reference assets (same SHA-256):
otherwise the two friction maps would be placed from different masks and would not lie under the same visual.
Everything is checked when the study starts, never in front of a participant.
"""
from __future__ import annotations

import hashlib
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

from kiosk.bundle.archive import MANIFEST, Bundle, open_bundle
from kiosk.contract.errors import KioskError
from kiosk.bundle.manifest import BundleError
from kiosk.bundle.signature import load_trusted_keys
from kiosk.study.config import StudyConfig

REFERENCE_ASSETS = ("visual", "sketch", "mask")


class StudyBundleError(KioskError):
    """A study bundle that cannot be used; the message names the condition, the garment and the problem."""


@dataclass(frozen=True)
class StudyBundle:
    condition: str
    garment: str
    path: Path
    bundle: Bundle

    @property
    def key(self) -> str:
        """The name the daemon serves this bundle under (conditions share garment ids, so the condition is in it)."""
        return f"{self.condition}:{self.garment}"

    def identity(self) -> dict:
        m = self.bundle.manifest
        return {"garment_id": m.garment_id, "model_version": m.model_version, "method": m.method,
                "manifest_sha256": hashlib.sha256((self.bundle.root / MANIFEST).read_bytes()).hexdigest(),
                "key_id": self.bundle.key_id, "file": str(self.path)}


class StudyBundles:
    def __init__(self, config: StudyConfig, items: dict[tuple[str, str], StudyBundle], workdir: Path) -> None:
        self.config = config
        self.items = items
        self._workdir = workdir

    def get(self, condition: str, garment: str) -> StudyBundle:
        return self.items[(condition, garment)]

    def identities(self) -> dict[str, dict[str, dict]]:
        """condition -> garment -> identity, as written into the log at session start."""
        out: dict[str, dict[str, dict]] = {}
        for (c, g), b in sorted(self.items.items()):
            out.setdefault(c, {})[g] = b.identity()
        return out

    def visual_file(self, garment: str) -> Path:
        """The ground-truth visual shown on both halves (identical in every condition's bundle; checked)."""
        b = self.get(self.config.reference, garment).bundle
        return b.root / b.manifest.assets["visual"]

    def close(self) -> None:
        shutil.rmtree(self._workdir, ignore_errors=True)


def _check_one(sb: StudyBundle, kind: str = "haptic") -> None:
    m = sb.bundle.manifest
    where = f"bundle {sb.path} (condition {sb.condition}, garment {sb.garment})"
    if m.garment_id != sb.garment:
        raise StudyBundleError(f"{where} is for garment {m.garment_id!r}, not {sb.garment!r}: wrong file?")
    missing = [a for a in REFERENCE_ASSETS if a not in m.assets]
    if missing:
        raise StudyBundleError(f"{where} has no reference asset(s) {', '.join(missing)}; the A/B study shows the "
                               "ground-truth visual and places the friction map by the reference mask (re-export "
                               "the bundle with its reference assets)")
    for a in REFERENCE_ASSETS:
        try:
            sb.bundle.asset(a)
        except BundleError as exc:
            raise StudyBundleError(f"{where}: {exc}") from None
    want = "tactile" if kind == "haptic" else "visual"
    if not {want, "full"} & set(m.graphs):
        raise StudyBundleError(f"{where} has no graph that computes {want} output (a {kind} study needs one)")


def open_study_bundles(config: StudyConfig, *, workdir: Path | None = None) -> StudyBundles:
    """Verify and check every (condition, garment) bundle of the study; raise StudyBundleError on the first problem."""
    trusted = load_trusted_keys(config.trusted_keys) if config.trusted_keys else None
    tmp = Path(tempfile.mkdtemp(prefix="vtkiosk-study-", dir=workdir))
    items: dict[tuple[str, str], StudyBundle] = {}
    try:
        conditions = [config.reference, *config.comparisons]
        for garment in config.garments:
            assets: dict[str, str] | None = None
            for cond in conditions:
                path = config.bundle_path(cond, garment)
                try:
                    bundle = open_bundle(path, trusted, workdir=tmp, allow_unsigned=config.allow_unsigned)
                except BundleError as exc:
                    raise StudyBundleError(f"bundle {path} (condition {cond}, garment {garment}): {exc}") from None
                sb = StudyBundle(cond, garment, path, bundle)
                _check_one(sb, config.kind)
                digests = {a: bundle.manifest.files[bundle.manifest.assets[a]] for a in REFERENCE_ASSETS}
                if assets is None:
                    assets = digests
                elif digests != assets:
                    differ = ", ".join(a for a in REFERENCE_ASSETS if digests[a] != assets[a])
                    raise StudyBundleError(f"garment {garment}: the {cond} bundle's reference {differ} differ from "
                                           f"the {config.reference} bundle's; all conditions must be exported from "
                                           "the same garment data so both friction maps lie under the same visual")
                items[(cond, garment)] = sb
        return StudyBundles(config, items, tmp)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
