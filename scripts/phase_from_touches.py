"""How much of the flat-to-oracle gap could a model close by placing the weave from the training touches alone?

docs/training.md ("What the gap is made of") says the gap off the touches is mostly the weave's phase, and that the
synthetic weave's periodic part is locked to frame coordinates, so a model that saw absolute position could in
principle learn its phase from the touches. This measures that bound directly, without a network: the weave left on
the touches once the `shape-oracle` is taken away (the recorded slopes, sensor blur and registration jitter as a
model sees them) is fitted with plane waves in frame coordinates (orthogonal matching pursuit: each wave's
frequency from the touches' zero-padded spectrum, refined by least squares, then every amplitude refitted), and the
fitted weave is scored off the touches on the evaluation crop, alone and on top of the `shape-oracle`. A plane wave
(with its harmonics: a ridge profile) is what a frame-locked positional feature most directly gives a network; the
fitted rows are what such a model would score with the fabric's folds and seams known exactly and only the weave's
place learnt from its touches. `--samples` fits the truth instead, at the touches' pixels or everywhere: ceilings
that separate what the touches say from what the wave family can hold.

    .venv/bin/python scripts/phase_from_touches.py data/hard640 KnitJacket SatinShirt CorduroyTrousers DenimShorts \
        --waves 3 --samples touches --json docs/compare_1k/phase_from_touches/touches.json
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from trainer.augment import eval_crop_origin, resolve_crop  # noqa: E402
from trainer.data.touchclothing import DatasetError, find_garment, friction_scale, load_garment  # noqa: E402
from trainer.evaluate import Context  # noqa: E402
from trainer.metrics import full_field_scores  # noqa: E402
from trainer.references import exported_head, weave_period_px  # noqa: E402

FIGURES = ("full_angle_deg_outside", "full_angle_deg_outside_lines", "full_angle_deg_outside_open")
MIN_PERIOD_PX = 2.5   # near the pixel grid's 2 px limit the sensor's blur leaves nothing to place
REFINE_ROUNDS = 4     # each shrinks the local frequency grid fourfold
PAD = 2               # spectrum zero-padding: frequency steps of 2 pi / (PAD P) rad/px


SAMPLES = ("touches", "truth-at-touches", "truth")


def samples(g, shape_gx: np.ndarray, shape_gy: np.ndarray, source: str = "touches"):
    """(x, y, weave gx, weave gy) to fit, in padded-frame pixels, less the shape-oracle. `touches`: the recorded
    slopes at every contact pixel of the training touches (jitter and sensor blur in, as a model sees them);
    `truth-at-touches`: the full-field truth at the same pixels (what perfect touches would say); `truth`: the truth
    over the whole garment (the fit's own ceiling: the phase known everywhere)."""
    if source == "truth":
        ft = g.full_tactile
        yy, xx = np.nonzero(g.mask)
        return (xx.astype(np.float64), yy.astype(np.float64),
                (ft.gx - shape_gx)[yy, xx].astype(np.float64), (ft.gy - shape_gy)[yy, xx].astype(np.float64))
    x, y, wx, wy = touch_samples(g, shape_gx, shape_gy)
    if source == "truth-at-touches":
        ft, xi, yi = g.full_tactile, x.astype(int), y.astype(int)
        wx = (ft.gx[yi, xi] - shape_gx[yi, xi]).astype(np.float64)
        wy = (ft.gy[yi, xi] - shape_gy[yi, xi]).astype(np.float64)
    return x, y, wx, wy


def touch_samples(g, shape_gx: np.ndarray, shape_gy: np.ndarray):
    """(x, y, weave gx, weave gy) at every contact pixel of the training touches: the recorded slopes less the
    shape-oracle at the recorded place."""
    xs, ys, wx, wy = [], [], [], []
    for t in g.touches.get("train", []):
        r = t.rect
        yy, xx = np.mgrid[r.y:r.y + r.h, r.x:r.x + r.w]
        c = t.contact & (yy < shape_gx.shape[0]) & (xx < shape_gx.shape[1])
        xs.append(xx[c]), ys.append(yy[c])
        wx.append(t.gx[c] - shape_gx[yy[c], xx[c]]), wy.append(t.gy[c] - shape_gy[yy[c], xx[c]])
    if not xs or not sum(len(a) for a in xs):
        raise SystemExit(f"{g.name}: no training touch with contact; nothing to fit")
    return tuple(np.concatenate(a).astype(np.float64) for a in (xs, ys, wx, wy))


def _design(k: np.ndarray, x: np.ndarray, y: np.ndarray, harmonics: int = 1) -> np.ndarray:
    """Columns of a height h = sum_m a_m sin(m k.x) + b_m cos(m k.x) per wave (m = 1..harmonics: a periodic ridge
    profile, not only a sinusoid), as slopes stacked (gx rows, then gy rows)."""
    cols = []
    for kx0, ky0 in k:
        for m in range(1, harmonics + 1):
            kx, ky = m * kx0, m * ky0
            ph = kx * x + ky * y
            c, s = np.cos(ph), np.sin(ph)
            cols += [np.concatenate([kx * c, ky * c]), np.concatenate([-kx * s, -ky * s])]
    return np.stack(cols, 1)


def fit_waves(x, y, gx, gy, size: int, waves: int, harmonics: int = 1) -> list[tuple[np.ndarray, np.ndarray]]:
    """Greedy plane-wave fits of the slopes (gx, gy) sampled at (x, y): after each new wave every amplitude is
    refitted (orthogonal matching pursuit). Returns, after each of 1..waves waves, the wave vectors (n, 2) in
    rad/px and their amplitudes (sin, cos per wave and harmonic, in `_design`'s column order)."""
    n = PAD * size
    k1 = 2 * np.pi * np.fft.fftfreq(n)
    kx, ky = np.meshgrid(k1, k1)
    k2 = kx * kx + ky * ky
    allowed = (k2 > 0) & (k2 <= (2 * np.pi / MIN_PERIOD_PX) ** 2)
    xi, yi = x.astype(int), y.astype(int)
    rx, ry = gx.copy(), gy.copy()
    chosen: list[tuple[float, float]] = []
    out = []
    for _ in range(waves):
        fx, fy = np.zeros((n, n)), np.zeros((n, n))
        np.add.at(fx, (yi, xi), rx)
        np.add.at(fy, (yi, xi), ry)
        sx, sy = np.fft.fft2(fx), np.fft.fft2(fy)
        # the slope of a wave of height e^{i k.x} is i k e^{i k.x}: project both slopes on it
        score = np.where(allowed, np.abs(kx * sx + ky * sy) ** 2 / np.maximum(k2, 1e-12), 0.0)
        j = np.unravel_index(int(np.argmax(score)), score.shape)
        k = np.array([kx[j], ky[j]])
        # refine the frequency below the padded spectrum's grid: exact least squares on a local grid, shrunk
        # around the best point each round (a phase drift of k-error x garment width must stay well under a radian)
        best, span, r = (np.inf, k), 2 * np.pi / n, np.concatenate([rx, ry])
        for _round in range(REFINE_ROUNDS):
            centre = best[1]
            for dx in np.linspace(-span, span, 9):
                for dy in np.linspace(-span, span, 9):
                    kk = centre + (dx, dy)
                    a = _design(kk[None], x, y, harmonics)
                    coef, *_ = np.linalg.lstsq(a, r, rcond=None)
                    err = float(((a @ coef - r) ** 2).sum())
                    if err < best[0]:
                        best = (err, kk)
            span /= 4
        chosen.append(tuple(best[1]))
        ks = np.array(chosen)
        a = _design(ks, x, y, harmonics)
        coef, *_ = np.linalg.lstsq(a, np.concatenate([gx, gy]), rcond=None)
        res = np.concatenate([gx, gy]) - a @ coef
        rx, ry = res[:len(gx)], res[len(gx):]
        out.append((ks.copy(), coef.copy()))
    return out


def render(ks: np.ndarray, coef: np.ndarray, shape: tuple[int, int], harmonics: int = 1
           ) -> tuple[np.ndarray, np.ndarray]:
    """The fitted waves' slopes over a (H, W) padded frame."""
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64)
    gx, gy = np.zeros(shape), np.zeros(shape)
    ks = np.array([m * k for k in ks for m in range(1, harmonics + 1)])
    for (kx, ky), a, b in zip(ks, coef[0::2], coef[1::2]):
        ph = kx * xx + ky * yy
        q = a * np.cos(ph) - b * np.sin(ph)
        gx += kx * q
        gy += ky * q
    return gx.astype(np.float32), gy.astype(np.float32)


def garment_rows(data: Path, name: str, waves: int, crop: int, harmonics: int = 1,
                 source: str = "touches") -> dict:
    try:
        g = load_garment(find_garment(data, name))
    except DatasetError as exc:
        raise SystemExit(f"no garment {name} in {data}: {exc}") from exc
    side = resolve_crop(crop, g.mask)
    ctx = Context(g, side, eval_crop_origin(g.mask, side), float(friction_scale(g)))
    truth, o, split = ctx.truth(), ctx.oracle(), ctx.weave_oracles()
    if truth is None or o is None or split is None:
        raise SystemExit(f"{g.name}: needs full-field truth and a stated weave period (synthetic garments)")
    shape = split[0]
    outside = ctx.obj & ~ctx.inside
    weave = [ctx.crop(a - b)[outside] for a, b in ((o.gx, shape.gx), (o.gy, shape.gy))]
    energy = float(sum((w.astype(np.float64) ** 2).sum() for w in weave))

    def scores(gx, gy, fitted=None):
        s, _ = full_field_scores(ctx.crop(gx), ctx.crop(gy), truth[0], truth[1], ctx.obj, ctx.inside, ctx.scale,
                                 ctx.origin, ctx.near_lines)
        row = {k: float(s[k]) for k in FIGURES}
        if fitted is not None:   # the share of the oracle's weave (slopes, off the touches) the fit explains
            miss = sum(((w - ctx.crop(f)[outside]).astype(np.float64) ** 2).sum() for w, f in zip(weave, fitted))
            row["weave_explained_outside"] = float(1.0 - miss / energy) if energy > 0 else None
        return row

    zero = np.zeros_like(o.gx)
    rows = {"flat": scores(zero, zero), "oracle": scores(o.gx, o.gy), "shape-oracle": scores(shape.gx, shape.gy)}
    x, y, wx, wy = samples(g, shape.gx, shape.gy, source)
    waves_found = []
    for ks, coef in fit_waves(x, y, wx, wy, g.mask.shape[0], waves, harmonics):
        fx, fy = render(ks, coef, g.mask.shape, harmonics)
        fx, fy = fx * g.mask, fy * g.mask
        n = len(ks)
        rows[f"waves-{n}"] = scores(exported_head(fx, g.mask), exported_head(fy, g.mask), (fx, fy))
        rows[f"shape-oracle+waves-{n}"] = scores(exported_head(shape.gx + fx, g.mask),
                                                 exported_head(shape.gy + fy, g.mask), (fx, fy))
        waves_found = [{"period_px": float(2 * np.pi / np.hypot(*k)),
                        "angle_deg": float(np.degrees(np.arctan2(k[1], k[0])))} for k in ks]
    flat, best = rows["flat"], rows["oracle"]
    for r in rows.values():
        f, b, v = flat["full_angle_deg_outside"], best["full_angle_deg_outside"], r["full_angle_deg_outside"]
        r["gap_closed_outside"] = float((f - v) / (f - b)) if abs(f - b) > 1e-9 else None
    return {"garment": g.name, "samples": source, "crop": side, "touches": len(g.touches.get("train", [])),
            "touch_pixels": int(len(x)), "weave_period_px": weave_period_px(g), "rows": rows, "waves": waves_found}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", type=Path, help="dataset folder (e.g. data/hard640)")
    ap.add_argument("garments", nargs="+", help="garment names (e.g. KnitJacket)")
    ap.add_argument("--waves", type=int, default=3, help="plane waves to fit (rows for 1..N)")
    ap.add_argument("--harmonics", type=int, default=3, help="harmonics per wave (a ridge profile, 1 = sinusoid)")
    ap.add_argument("--samples", choices=SAMPLES, default="touches",
                    help="what the waves are fitted to (touches: as a model sees them; the others are ceilings)")
    ap.add_argument("--crop", type=int, default=512, help="evaluation crop side (the cpu preset's)")
    ap.add_argument("--json", type=Path, help="write the rows here")
    a = ap.parse_args(argv)
    if a.waves < 1 or a.harmonics < 1:
        ap.error("--waves and --harmonics must be at least 1")
    results = [garment_rows(a.data, n, a.waves, a.crop, a.harmonics, a.samples) for n in a.garments]
    for res in results:
        found = ", ".join(f"{w['period_px']:.2f} px at {w['angle_deg']:.1f} deg" for w in res["waves"])
        print(f"\n{res['garment']} [{res['samples']}] ({res['touches']} touches, {res['touch_pixels']} pixels "
              f"fitted; waves: {found})")
        print(f"{'row':26s} {'outside':>8s} {'by a line':>9s} {'open':>7s} {'gap':>6s} {'weave R2':>9s}")
        for name, r in res["rows"].items():
            gap = r["gap_closed_outside"]
            r2 = r.get("weave_explained_outside")
            print(f"{name:26s} {r[FIGURES[0]]:8.3f} {r[FIGURES[1]]:9.3f} {r[FIGURES[2]]:7.3f} "
                  f"{'' if gap is None else f'{100 * gap:5.0f}%'} {'' if r2 is None else f'{r2:9.2f}'}")
    if a.json:
        a.json.write_text(json.dumps({"data": a.data.name, "samples": a.samples, "waves": a.waves,
                                      "harmonics": a.harmonics, "garments": results}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
