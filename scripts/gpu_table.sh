#!/bin/bash
# The close methods' comparison trained on one GPU, inside a fixed time budget: `ours`, `no-tactile-gan` and
# `ours-no-gan` (the full table's recipes) on the hard garments at a larger crop, all runs side by side on the one
# GPU, each at the longest schedule the budget allows (measured first, then fixed for every run, so the rows share
# one recipe), scored with `vtkiosk eval --compare`, and packed into $OUT for a machine that keeps no state.
#
#   OUT=/tmp/gpu scripts/gpu_table.sh [BUDGET_S]      # data: data/hard640 (vtkiosk data synth ... --frame 640x480)
#
# Environment: DATA, GARMENTS, CROP (768: the largest grid multiple a 900 px padded frame holds), DEVICE (cuda),
# PY (python3), WORK (a fresh /tmp/gpu_table.XXXXXX; a given one must not hold runs yet), MIN_STEPS (2500: below
# it the run drops no-tactile-gan to afford them), MAX_STEPS (20000), CAL_STEPS (80), METHODS (the three) and STEPS
# (skips the calibration), EXTRA (more `--set`s for every run), PACK (weights sheets infer: what to pack beside the
# table and log), SCORE (1; 0 skips the on-device scoring: the packed fp16 weights are scored elsewhere with
# `vtkiosk eval --compare`, and training gets all of BUDGET_S but the packing's reserve, 20 s, 45 s with infer).
# RECIPES (a file of lines `LABEL ARGS...`, `#` comments: each LABEL is a run folder trained with its own ARGS,
# --method included, instead of the built-in recipes; METHODS then defaults to its labels and the weights pack in
# files of at most 15 MiB, weights-1.tar on, since a lease returns 8 files at most: scripts/recipes/).
# RESUME (1: continue, in the WORK folder a deadline left behind, every run short of STEPS, which it needs; finished
# runs are left as they are and all are scored and packed as one table; a warm machine keeps the folder, which the
# log names). Every stage has its own deadline inside BUDGET_S (default 540), so the packing always runs; the exit
# status is 1 when a run failed.
set -u
START=$(date +%s)
# shellcheck source=scripts/recipes_lib.sh
. "$(dirname "${BASH_SOURCE[0]}")/recipes_lib.sh"
BUDGET=${1:-540}
: "${OUT:?set OUT to the folder that collects the results}"
PY=${PY:-python3}
DATA=${DATA:-data/hard640}
GARMENTS=${GARMENTS:-DenimShorts CorduroyTrousers KnitJacket SatinShirt}
CROP=${CROP:-768}
DEVICE=${DEVICE:-cuda}
W=${WORK:-$(mktemp -d /tmp/gpu_table.XXXXXX)}
# a warm machine keeps the last call's folder: its finished runs would be packed again as this call's, unless the
# call says it continues them
if [ "${RESUME:-0}" = 1 ]; then
  if [ -z "${WORK:-}" ] || [ ! -d "$W/runs" ] || [ -z "${STEPS:-}" ]; then
    echo "gpu_table.sh: RESUME=1 needs WORK, a folder holding an earlier call's runs, and that call's STEPS" >&2; exit 2
  fi
elif [ -e "$W/runs" ] || [ -e "$W/cal" ]; then
  echo "gpu_table.sh: $W already holds runs; give another WORK (or none, for a fresh folder), or RESUME=1 to continue them" >&2
  exit 2
fi
MIN_STEPS=${MIN_STEPS:-2500}
MAX_STEPS=${MAX_STEPS:-20000}
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1
# stage deadlines, seconds from START
TRAIN_END=$((BUDGET * 64 / 100)); EVAL_END=$((BUDGET * 84 / 100)); TABLE_END=$((BUDGET * 94 / 100))
# scored elsewhere: training gets all but a fixed reserve for the packing (about 10 s measured; 20 s kept) and the
# inference timing (its own 25 s timeout), so a longer budget is all training
PACK=${PACK:-weights sheets infer}
RESERVE=20; [[ " $PACK " == *" infer "* ]] && RESERVE=45
[ "${SCORE:-1}" = 1 ] || { TRAIN_END=$((BUDGET - RESERVE)); EVAL_END=$TRAIN_END; TABLE_END=$TRAIN_END; }
mkdir -p "$OUT" "$W"
el() { echo $(( $(date +%s) - START )); }
left() { local r=$(( $1 - $(el) )); [ $r -lt 1 ] && r=1; echo $r; }
log() { echo "[$(el) s] $*" | tee -a "$OUT/gpu_table.log"; }

COMMON="--data $DATA --preset cpu --set data.crop=$CROP --set train.threads=1 --set train.progress=false \
--set train.device=$DEVICE --set train.ema=0.999 ${EXTRA:-}"
recipe() {   # the full table's recipe of each method (docs/training.md), or the RECIPES file's line
  if [ -n "${RECIPES:-}" ]; then
    local line; line=$(recipe_args "$RECIPES" "$1")
    [ -n "$line" ] || { echo "gpu_table.sh: no recipe for $1 in $RECIPES" >&2; return 1; }
    echo "$line"; return
  fi
  case $1 in
    ours|no-tactile-gan) echo "--method $1 --set loss.tactile_r1=10 --set loss.diffaug=color,translation,cutout" ;;
    ours-no-gan) echo "--method ours-no-gan --set optim.lr_policy=linear --set loss.diffaug=" ;;
  esac
}
train_all() {  # train_all ROOT STEPS DEADLINE EXTRA... : every (garment, method) side by side
  local root=$1 steps=$2 deadline=$3; shift 3
  for g in $GARMENTS; do for m in $METHODS; do
    mkdir -p "$root/$g"
    local more=()
    if [ "${RESUME:-0}" = 1 ]; then   # a finished run is left alone; a stopped one continues from its checkpoint
      local at; at=$(run_step "$PY" "$root/$g/$m")
      [ "$at" -ge "$steps" ] && continue
      [ -e "$root/$g/$m/checkpoints/latest.pt" ] && more=(--resume)
      log "$g/$m: ${more[*]:-starting} at step $at of $steps"
    fi
    local r; r=$(recipe "$m") || { log "$g/$m: no recipe; not trained"; continue; }
    timeout -s TERM "$(left "$deadline")" $PY -m vtkiosk train $COMMON $r --garment "$g" \
      --steps "$steps" "$@" "${more[@]}" --out "$root/$g/$m" >> "$root/$g/$m.log" 2>&1 &
  done; done
  wait
}

{ nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>/dev/null || echo "no nvidia-smi"
  $PY -c "import torch; print('torch', torch.__version__, 'cuda', torch.version.cuda, torch.cuda.is_available())"
  lscpu | grep -m1 "Model name"; nproc; } > "$OUT/machine.txt" 2>&1
log "machine: $(tr '\n' ' ' < "$OUT/machine.txt")"
log "deadlines: training ${TRAIN_END} s, scoring ${EVAL_END} s, table ${TABLE_END} s of ${BUDGET} s; work folder $W"

if [ -n "${RECIPES:-}" ]; then
  [ -f "$RECIPES" ] || { log "RECIPES: no file $RECIPES"; exit 2; }
  METHODS=${METHODS:-$(recipe_labels "$RECIPES")}
  [ -n "${STEPS:-}" ] || { log "RECIPES needs STEPS (the calibration fits the built-in recipes only)"; exit 2; }
fi

# 1. the step time of all runs side by side (CAL_STEPS, 80: the second half's, so the warm-up is left out; the CLIP
#    discriminator on from the start, so its step is in the time and its code has run here before the real runs;
#    10 % kept for the real runs' validation and sample sheets, which the calibration leaves out)
METHODS=${METHODS:-ours no-tactile-gan ours-no-gan}
if [ -n "${STEPS:-}" ]; then
  N=$(( $(echo $GARMENTS | wc -w) * $(echo $METHODS | wc -w) ))
  log "training $N runs ($METHODS) for $STEPS steps (given)"
else
  train_all "$W/cal" "${CAL_STEPS:-80}" $((BUDGET * 15 / 100)) --set train.val_every=1000 \
    --set train.sample_every=1000 --set train.ckpt_every=1000 --set loss.clip_start=0
  OK=""
  for m in $METHODS; do
    if ls "$W"/cal/*/"$m"/metrics.json > /dev/null 2>&1; then OK="$OK $m"; else
      log "calibration of $m failed; dropped. Its log:"; tail -n 25 "$(ls "$W"/cal/*/"$m".log | head -n 1)" >> "$OUT/gpu_table.log"
    fi
  done
  METHODS=${OK# }
  SPS=$($PY -c "import json, sys, pathlib; t = [json.loads(p.read_text())['train'] \
for p in pathlib.Path(sys.argv[1]).glob('*/*/metrics.json')]; \
v = [1.1 * (r.get('seconds_per_step_steady') or r['seconds_per_step']) for r in t]; \
print(round(max(v), 4) if v else '')" "$W/cal")
  if [ -z "$SPS" ] || [ -z "$METHODS" ]; then
    log "calibration failed; its logs:"; tail -n 30 "$W"/cal/*/*.log >> "$OUT/gpu_table.log"
    tar -C "$W" -czf "$OUT/calibration_logs.tar.gz" cal; exit 1
  fi
  N=$(( $(echo $GARMENTS | wc -w) * $(echo $METHODS | wc -w) ))
  STEPS=$($PY -c "s=int(($TRAIN_END-$(el)-30)/$SPS)//50*50; print(max(50, min(s, $MAX_STEPS)))")
  if [ "$STEPS" -lt "$MIN_STEPS" ] && [ "$METHODS" = "ours no-tactile-gan ours-no-gan" ]; then
    METHODS="ours ours-no-gan"; N=$((N * 2 / 3))   # two methods: each run gets 3/2 of its share of the GPU
    STEPS=$($PY -c "s=int(($TRAIN_END-$(el)-30)/($SPS*2/3))//50*50; print(max(50, min(s, $MAX_STEPS)))")
  fi
  log "calibration: ${SPS} s/step (steady, +10 %) with all runs side by side; training $N runs ($METHODS)\
 for $STEPS steps"
fi

# 2. the runs (a run still going at the deadline gets SIGTERM, saves its latest checkpoint, and is marked so)
train_all "$W/runs" "$STEPS" "$TRAIN_END"
FAILED=0
for g in $GARMENTS; do for m in $METHODS; do
  if [ ! -f "$W/runs/$g/$m/metrics.json" ]; then
    FAILED=$((FAILED + 1)); log "$g/$m: failed; its log ends:"; tail -n 5 "$W/runs/$g/$m.log" >> "$OUT/gpu_table.log"
    continue
  fi
  log "$g/$m: $($PY -c "import json; t=json.load(open('$W/runs/$g/$m/metrics.json'))['train']; \
print(t['step'], 'steps', t['seconds_per_step'], 's/step', 'stopped early' if t['stopped_early'] else '')" 2>&1 | tail -n 1)"
done; done

# 3. scores: each run scored in its own process (cached beside the run), then one table from the caches
if [ "${SCORE:-1}" = 1 ]; then
  for g in $GARMENTS; do for m in $METHODS; do
    timeout "$(left "$EVAL_END")" $PY -m vtkiosk eval --compare "$W/runs/$g/$m" --which latest --no-swap \
      --out "$W/score/$g-$m" > "$W/runs/$g/$m.eval.log" 2>&1 &
  done; done
  wait
  ARGS=(); for m in $METHODS; do for g in $GARMENTS; do ARGS+=("$W/runs/$g/$m"); done; done
  timeout "$(left "$TABLE_END")" $PY -m vtkiosk eval --compare "${ARGS[@]}" --which latest --ours ours --no-swap \
    --out "$W/table" > "$W/table.log" 2>&1
  log "table: exit $? ($(ls "$W/table" 2>/dev/null | tr '\n' ' '))"
fi

# 4. the generator's inference time at the paper's 1536 px, beside the paper's 0.19 s
[[ " $PACK " == *" infer "* ]] && timeout 25 $PY scripts/gpu_infer_time.py --run "$W/runs/DenimShorts/ours" --out "$OUT/gpu_infer.json" --repeats 20 \
  >> "$OUT/gpu_table.log" 2>&1

# 5. pack: the table, each run's record and scores, and its generator in fp16 (to score again elsewhere)
$PY - "$W" "$DATA" <<'EOF'
import pathlib, sys, torch
w, data = pathlib.Path(sys.argv[1]), sys.argv[2]
for ck_path in w.glob("runs/*/*/checkpoints/latest.pt"):
    ck = torch.load(ck_path, map_location="cpu", weights_only=False)
    ck.pop("train_state", None)
    ck["generator"] = {k: v.half() if v.is_floating_point() else v for k, v in ck["generator"].items()}
    ck["config"]["garment"] = f"{data}/{pathlib.Path(ck['config']['garment']).name}"  # no machine's own path
    out = ck_path.parent.parent / "weights"
    out.mkdir(exist_ok=True)
    torch.save(ck, out / "latest.pt")
EOF
mkdir -p "$W/table"
tar -C "$W" -czf "$OUT/table.tar.gz" --exclude='*.pt' --exclude=samples --exclude='sheet_*' table runs
SHEETS=$(cd "$W" && ls table/sheet_* 2>/dev/null)
[[ " $PACK " == *" sheets "* ]] && [ -n "$SHEETS" ] && tar -C "$W" -cf "$OUT/sheets.tar" $SHEETS
if [[ " $PACK " == *" weights "* ]] && [ -n "${RECIPES:-}" ]; then
  # many labels: fill files of at most 15 MiB in label order (a lease returns 8 files, 16 MiB each)
  n=1; size=0; files=()
  for m in $METHODS; do for d in $(cd "$W" && ls -d runs/*/"$m"/weights 2>/dev/null); do
    s=$(du -sk "$W/$d" | cut -f1)
    if [ ${#files[@]} -gt 0 ] && [ $((size + s)) -gt 15360 ]; then
      tar -C "$W" -cf "$OUT/weights-$n.tar" "${files[@]}"; n=$((n + 1)); size=0; files=()
    fi
    files+=("$d"); size=$((size + s))
  done; done
  [ ${#files[@]} -gt 0 ] && tar -C "$W" -cf "$OUT/weights-$n.tar" "${files[@]}"
elif [[ " $PACK " == *" weights "* ]]; then
  for m in $METHODS; do
    tar -C "$W" -cf "$OUT/weights-$m.tar" $(cd "$W" && ls -d runs/*/"$m"/weights)
  done
fi
log "packed: $(ls -s "$OUT" | tr '\n' ' ')"
[ "$FAILED" = 0 ] || { log "$FAILED run(s) failed (above)"; exit 1; }
