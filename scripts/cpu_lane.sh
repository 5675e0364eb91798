#!/bin/bash
# One lane of a recipes file trained on this CPU: the LABELs given, one after another, single-threaded, each on the
# blind test's protocol T (docs/training.md, "Which views where") plus its RECIPES line. Two lanes side by side use
# two cores. A lane resumes: a run whose record reached STEPS is skipped, one with a checkpoint continues from it, so
# a lane stopped by the end of a session is started again with the same command.
#
#   GARMENT=SatinShirt ROOT=runs/s60/SatinShirt scripts/cpu_lane.sh gaugan ours-txr-s3 ...
#
# Environment: GARMENT and ROOT (required), RECIPES (scripts/recipes/blind_lift.txt), DATA (data/hard640),
# STEPS (1000), PY (.venv/bin/python), EXTRA (more arguments for every run). Progress lines go to $ROOT/lane.log,
# each run's output to $ROOT/LABEL.log.
set -u
# shellcheck source=scripts/recipes_lib.sh
. "$(dirname "${BASH_SOURCE[0]}")/recipes_lib.sh"
: "${GARMENT:?set GARMENT}" "${ROOT:?set ROOT, the folder that holds the runs}"
RECIPES=${RECIPES:-scripts/recipes/blind_lift.txt}
DATA=${DATA:-data/hard640}
STEPS=${STEPS:-1000}
PY=${PY:-.venv/bin/python}
[ -f "$RECIPES" ] || { echo "cpu_lane.sh: no recipes file $RECIPES" >&2; exit 2; }
[ -d "$DATA" ] || { echo "cpu_lane.sh: no data folder $DATA" >&2; exit 2; }
[[ "$STEPS" =~ ^[1-9][0-9]*$ ]] || {
  echo "cpu_lane.sh: STEPS must be a positive whole number, not $STEPS" >&2; exit 2; }
[ $# -gt 0 ] || { echo "cpu_lane.sh: name the LABELs of $RECIPES to train" >&2; exit 2; }
T="--data $DATA --preset cpu --steps $STEPS --set train.ema=0.999 --set train.threads=1 --set train.progress=false"
T="$T ${EXTRA:-}"
mkdir -p "$ROOT"
log() { echo "$(date -u +%FT%TZ) $GARMENT $*" | tee -a "$ROOT/lane.log"; }
rc=0
for label in "$@"; do
  args=$(recipe_args "$RECIPES" "$label")
  [ -n "$args" ] || { log "$label: no recipe in $RECIPES; skipped"; rc=1; continue; }
  run=$ROOT/$label
  at=$(run_step "$PY" "$run")
  if [ "$at" -ge "$STEPS" ]; then log "$label: done ($at steps); skipped"; continue; fi
  more=(); [ -e "$run/checkpoints/latest.pt" ] && more=(--resume)
  log "$label: ${more[*]:-starting} at step $at"
  # shellcheck disable=SC2086  # T and args are word lists
  if "$PY" -m vtkiosk train $T $args --garment "$GARMENT" "${more[@]}" --out "$run" >> "$ROOT/$label.log" 2>&1; then
    log "$label: finished at step $(run_step "$PY" "$run")"
  else
    log "$label: failed (exit $?); see $ROOT/$label.log"; rc=1
  fi
done
exit $rc
