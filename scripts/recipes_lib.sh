# Sourced by scripts/gpu_table.sh and scripts/cpu_lane.sh: a recipes file's lines (`LABEL ARGS...`, `#` comments)
# and how far a run got, so the GPU lease and the CPU lanes read a recipes file the same way.
recipe_args() {     # recipe_args FILE LABEL: LABEL's arguments, empty when the file has no such line
  grep -v '^\s*#' "$1" | awk -v l="$2" '$1 == l { $1 = ""; print; exit }'
}
recipe_labels() {   # recipe_labels FILE: every label, in the file's order
  grep -v '^\s*#' "$1" | awk 'NF { print $1 }' | xargs
}
run_step() {        # run_step PY RUN: the step RUN's record reached (0: none yet)
  "$1" -c "import json, sys; print(json.load(open(sys.argv[1]))['train']['step'])" "$2/metrics.json" \
    2>/dev/null || echo 0
}
