#!/bin/bash
# Beside a training run that keeps only its latest checkpoints, copy one checkpoint every EVERY env
# steps into SNAPS/s<step>/<policy>_<init>/ and evaluate it on Table II's first TRIALS trials (one
# thread, nice 2), into OUT/s<step>/. scripts/checkpoint_curve.py then plots the points.
#
#   bash scripts/watch_checkpoints.sh RUN_DIR POLICY_INIT FIRST_STEP [EVERY] [TRIALS] [METHOD] [SNAPS] [OUT]
#   bash scripts/watch_checkpoints.sh runs/cont/mixed_stand_more mixed_stand 400000000
#
# Stop it with kill; a snapshot left half-evaluated has no table2_trials.npz and the plot refuses it.
set -u
RUN=${1:?run folder}; NAME=${2:?policy_init, e.g. mixed_stand}; next=${3:?first env step}
EVERY=${4:-10000000}; TRIALS=${5:-500}; METHOD=${6:-end_to_end}
SNAPS=${7:-runs/snaps}; OUT=${8:-experiments/results/end_to_end_curve}
PY=${PY:-.venv/bin/python}
[ -d "$RUN/checkpoints" ] || { echo "no checkpoints folder in $RUN" >&2; exit 1; }
while true; do
  latest=$(ls "$RUN/checkpoints" | grep -E '^[0-9]{12}$' | sort | tail -1)
  if [ -n "$latest" ]; then
    step=$((10#$latest))
    if [ -f "$RUN/checkpoints/$latest/commit_success.txt" ] && [ "$step" -ge "$next" ]; then
      d=$SNAPS/s$latest/$NAME
      mkdir -p "$d/checkpoints"
      cp "$RUN/config.json" "$d/"
      cp -r "$RUN/checkpoints/$latest" "$d/checkpoints/"
      echo "$(date -u +%T) snapshot $step"
      BIPED_SWITCH_NTHREAD=1 nice -n 2 "$PY" -m biped_switch.evaluate multi --methods "$METHOD" \
        --trials "$TRIALS" --runs "$SNAPS/s$latest" --out "$OUT/s$latest" --fig5-trial -1 \
        > "$SNAPS/s$latest.log" 2>&1
      echo "$(date -u +%T) evaluated $step rc=$?"; tail -1 "$SNAPS/s$latest.log"
      next=$(( (step / EVERY + 1) * EVERY ))
    fi
  fi
  sleep 60
done
