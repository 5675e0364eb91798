"""The trained generator's inference time on a GPU at the paper's 1536 x 1536, beside the paper's 0.19 s.

    python scripts/gpu_infer_time.py --run runs/DenimShorts/ours --out gpu_infer.json [--size 1536] [--repeats 30]

Times PyTorch eager in float32 and under bfloat16 autocast (CUDA events, after warm-up), with each one's peak GPU
memory, and states what bfloat16 costs: the largest visual difference and the mean angle between the two tactile
outputs, against float32 (the synthetic garment's truth is not defined at this size, so this is the quantisation's
error, not the model's). The input is the run's own sketch and mask, resized to the size.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from trainer.checkpoint import load_generator  # noqa: E402
from trainer.metrics import angular_error_deg  # noqa: E402


def timed(fn, repeats: int) -> tuple[list[float], object]:
    for _ in range(3):
        out = fn()
    torch.cuda.synchronize()
    times = []
    for _ in range(repeats):
        a, b = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
        a.record()
        out = fn()
        b.record()
        torch.cuda.synchronize()
        times.append(a.elapsed_time(b) / 1000.0)
    return times, out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", required=True, type=Path)
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--size", type=int, default=1536)
    ap.add_argument("--repeats", type=int, default=30)
    a = ap.parse_args()
    if not torch.cuda.is_available():
        print("no GPU: nothing to time", file=sys.stderr)
        return 2
    import cv2
    from trainer.data.touchclothing import load_garment
    from kiosk.contract.sketch import network_input

    net, info = load_generator(a.run, "latest")
    net = net.cuda().eval()
    g = load_garment(Path(info["garment"]) if Path(info["garment"]).is_dir() else
                     Path("data/hard640") / Path(info["garment"]).name, tactile=False)
    sk = cv2.resize(g.sketch, (a.size, a.size), interpolation=cv2.INTER_AREA)
    mk = cv2.resize(g.mask.astype(np.uint8), (a.size, a.size), interpolation=cv2.INTER_NEAREST) > 0
    ni = network_input(sk, mk)
    sketch, mask = torch.from_numpy(ni.sketch).cuda(), torch.from_numpy(ni.mask).cuda()
    rows = {}
    outs = {}
    for name, ctx in (("float32", torch.autocast("cuda", enabled=False)),
                      ("bfloat16", torch.autocast("cuda", dtype=torch.bfloat16))):
        torch.cuda.reset_peak_memory_stats()
        with torch.no_grad(), ctx:
            times, out = timed(lambda: net(sketch, mask), a.repeats)
        outs[name] = [t.float().cpu() for t in out]
        rows[name] = {"median_s": float(np.median(times)), "p95_s": float(np.percentile(times, 95)),
                      "peak_gpu_mib": torch.cuda.max_memory_allocated() / 2**20, "repeats": a.repeats}
    (v32, t32), (v16, t16) = outs["float32"], outs["bfloat16"]
    finite = all(bool(torch.isfinite(t).all()) for t in (v16, t16))
    rows["bfloat16"].update({"vs_float32_visual_max_abs": float((v16 - v32).abs().max()),
                             "vs_float32_tactile_angle_deg": angular_error_deg(t16[0, 0], t16[0, 1], t32[0, 0],
                                                                              t32[0, 1], mask[0, 0].cpu() > 0),
                             "finite": finite})
    props = torch.cuda.get_device_properties(0)
    result = {"gpu": props.name, "torch": torch.__version__, "cuda": torch.version.cuda, "size": a.size,
              "run": a.run.name, "method": info["method"], "step": info["step"], "paper_seconds": 0.19,
              "paper_gpu": "one 24 GB RTX A5000 (the paper's implementation details)", "rows": rows}
    a.out.write_text(json.dumps(result, indent=2))
    print(f"{props.name}: {a.size} px, float32 median {rows['float32']['median_s'] * 1000:.1f} ms "
          f"(p95 {rows['float32']['p95_s'] * 1000:.1f}), bfloat16 {rows['bfloat16']['median_s'] * 1000:.1f} ms; "
          f"paper 190 ms")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
