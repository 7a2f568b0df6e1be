#!/bin/bash
# Evaluate chosen checkpoints of a finished DQN run on Table II's first TRIALS trials, each into
# OUT/s<step>/ (scripts/checkpoint_curve.py --method dqn then plots them). Each checkpoint is
# copied into SNAPS/s<step>/ with the run's config, since `evaluate multi --dqn` takes a run
# folder's latest checkpoint.
#
#   bash scripts/dqn_checkpoint_curve.sh RUN_DIR TRIALS OUT SNAPS STEP [STEP ...]
#   bash scripts/dqn_checkpoint_curve.sh runs/dqn_stand_more 500 experiments/results/dqn_curve \
#       runs/dqn_snaps 000011033600 000012057600
set -u
RUN=${1:?run folder}; TRIALS=${2:?trials}; OUT=${3:?out}; SNAPS=${4:?snapshot folder}; shift 4
PY=${PY:-.venv/bin/python}
for ck in "$@"; do
  [ -f "$RUN/checkpoints/$ck/progress.json" ] || { echo "no finished checkpoint $RUN/checkpoints/$ck" >&2; exit 1; }
  d=$SNAPS/s$ck
  mkdir -p "$d/checkpoints"
  cp "$RUN/config.json" "$d/"
  [ -d "$d/checkpoints/$ck" ] || cp -r "$RUN/checkpoints/$ck" "$d/checkpoints/"
  echo "$(date -u +%T) evaluating $ck"
  BIPED_SWITCH_NTHREAD=${NTHREAD:-2} nice -n 2 "$PY" -m biped_switch.evaluate multi --methods dqn \
    --trials "$TRIALS" --dqn "$d" --out "$OUT/s$ck" --fig5-trial -1 > "$d.log" 2>&1
  echo "$(date -u +%T) evaluated $ck rc=$?"; grep '^| dqn' "$OUT/s$ck/table2.md"
done
