#!/bin/bash
# Where does `ours`' tactile R1 blow up on a GPU? One command for one short GPU lease: the static check
# (scripts/gpu_r1_check.py), the in-training probe (scripts/gpu_r1_probe.py) and `ours` trained side by side on the
# one GPU with one suspect changed per run, then each run's R1 curve and final validation in one summary.
#
#   OUT=/tmp/r1 scripts/gpu_r1_variants.sh      # data/hard640 beside it (vtkiosk data synth ... --frame 640x480)
#
# Environment: DATA (data/hard640), GARMENT (SatinShirt: the 512 px run that diverged most), STEPS (600: every
# measured GPU run had left R1 ~1e-1 by step 450), CROP (512), PY (python3), WORK (/tmp/r1_variants), TRAIN_S (330:
# each run is stopped then, with a checkpoint, so the summary and packing always run).
set -u
: "${OUT:?set OUT to the folder that collects the results}"
PY=${PY:-python3}
DATA=${DATA:-data/hard640}
GARMENT=${GARMENT:-SatinShirt}
STEPS=${STEPS:-600}
CROP=${CROP:-512}
W=${WORK:-/tmp/r1_variants}
TRAIN_S=${TRAIN_S:-330}
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1
mkdir -p "$OUT" "$W"
START=$(date +%s)
{ nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>/dev/null || echo "no nvidia-smi"
  $PY -c "import torch; print('torch', torch.__version__, 'cuda', torch.version.cuda, torch.cuda.is_available())"
  lscpu | grep -m1 "Model name"; nproc; } > "$OUT/machine.txt" 2>&1
cat "$OUT/machine.txt"

RECIPE="--data $DATA --garment $GARMENT --preset cpu --method ours --steps $STEPS --set data.crop=$CROP \
--set train.threads=1 --set train.progress=false --set train.ema=0.999 --set loss.tactile_r1=10 \
--set loss.diffaug=color,translation,cutout --set train.val_every=$STEPS --set train.sample_every=$STEPS"
# `train` NAME PRELUDE ARGS...: one run in the background (PRELUDE: python run first), its log beside it
train() {
  local name=$1 pre=$2; shift 2
  timeout -s TERM "$TRAIN_S" $PY -c "import runpy, sys, torch; $pre; sys.argv = ['vtkiosk'] + sys.argv[1:]; \
runpy.run_module('vtkiosk', run_name='__main__')" train $RECIPE "$@" --out "$W/$name" > "$W/$name.log" 2>&1 &
}
$PY scripts/gpu_r1_check.py --out "$OUT/r1_check.json" > "$OUT/r1_check.txt" 2>&1 &
timeout -s TERM "$TRAIN_S" $PY scripts/gpu_r1_probe.py --data "$DATA" --garment "$GARMENT" --steps "$STEPS" --every 25 \
  --set data.crop=$CROP --set train.device=cuda --set train.val_every=$STEPS --set train.sample_every=$STEPS \
  --out "$W/probe" > "$W/probe.log" 2>&1 &
train cuda-nocudnn "torch.backends.cudnn.enabled = False" --set train.device=cuda
train cuda-noaug "pass" --set train.device=cuda --set loss.diffaug=
train cuda-deterministic "pass" --set train.device=cuda --set train.deterministic=true
train cuda-instancenorm "pass" --set train.device=cuda --set model.d_norm=instance
train cuda-nor1 "pass" --set train.device=cuda --set loss.tactile_r1=0
train cpu "pass" --set train.device=cpu --set train.threads=4
wait
echo "[$(( $(date +%s) - START )) s] runs done"

$PY - "$W" > "$OUT/summary.txt" <<'EOF'
import json, sys
from pathlib import Path
from trainer.checkpoint import read_checkpoint
w = Path(sys.argv[1])
print(f"{'run':20} {'R1@100':>9} {'R1@200':>9} {'R1@300':>9} {'R1@400':>9} {'R1@500':>9} {'R1 last':>9} "
      f"{'D_t last':>9} {'val t-angle':>11} {'s/step':>7}")
for run in sorted(p for p in w.iterdir() if p.is_dir()):
    m = run / "metrics.json"
    if not m.exists():
        print(f"{run.name:20} no metrics.json (see {run.name}.log)"); continue
    d = json.loads(m.read_text())["train"]
    hist = read_checkpoint(run, "latest")["train_state"]["history"]
    r1 = {h["step"]: h.get("d_tactile_r1") for h in hist}
    dt = [h.get("d_tactile") for h in hist if h.get("d_tactile") is not None]
    val = (d.get("val") or {})
    ang = next((v for k, v in val.items() if "angle" in k and isinstance(v, float)), float("nan"))
    f = lambda x: "-" if x is None else f"{x:9.3g}"
    last = hist[-1]["step"] if hist else None
    print(f"{run.name:20} " + " ".join(f(r1.get(s)) for s in (100, 200, 300, 400, 500, last))
          + f" {f(dt[-1] if dt else None)} {ang:11.3f} {d.get('seconds_per_step', float('nan')):7}")
EOF
cat "$OUT/summary.txt" "$OUT/r1_check.txt"
grep "\[probe\]" "$W/probe.log" | tee "$OUT/probe_rows.txt"
cp "$W/probe/r1_probe.jsonl" "$OUT/" 2>/dev/null
tar -C "$W" -czf "$OUT/runs.tar.gz" --exclude='*/samples' --exclude='*.pt' .   # checkpoints exceed what a lease returns
echo "[$(( $(date +%s) - START )) s] packed"
