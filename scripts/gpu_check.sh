#!/usr/bin/env bash
# The GPU host's check of the MJX path, as one device call (carry [".whl"], made by `make wheels`):
#   bash scripts/gpu_check.sh [STEP ...]    STEPs: mjx train estimator chunk (default: all four)
# Each bench prints one JSON object into $OUT (or ./gpu_check/ off the device tool) and has its own
# time limit, so one slow compile cannot eat the others' share of the 10-minute call.
set -uo pipefail
out=${OUT:-gpu_check}; mkdir -p "$out"
export PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv | tee "$out/nvidia_smi.csv"
bash scripts/gpu_run.sh true || exit 1  # installs the carried wheels into /tmp/site, once
export PYTHONPATH=/tmp/site:$PWD
python3 -c 'import jax, mujoco; print("jax", jax.__version__, jax.devices(), "mujoco", mujoco.__version__)' 2>&1 | tail -2
steps=" ${*:-mjx train estimator chunk} "
has() { [[ "$steps" == *" $1 "* ]]; }
# Env stepping with MJX at batch 8192 (7-artifact mixed tracks).
if has mjx; then timeout 200 python3 -m biped_switch.bench --backend mjx --batch 8192 --json > "$out/gpu_mjx_batch8192.json" 2> "$out/gpu_mjx_batch8192.err"; echo "mjx bench rc=$?"; fi
# One PPO chunk's worth: collection + updates with the gpu preset (MJX), compile time included.
if has train; then timeout 220 python3 -m biped_switch.bench --train --preset gpu --backend mjx --json > "$out/gpu_train.json" 2> "$out/gpu_train.err"; echo "train bench rc=$?"; fi
# The switch estimator on 100k points (the first epoch compiles).
if has estimator; then timeout 100 python3 -m biped_switch.bench --estimator --points 100000 --epochs 4 --json > "$out/gpu_estimator.json" 2> "$out/gpu_estimator.err"; echo "estimator bench rc=$?"; fi
# Two chunks of the real training command (gpu preset, MJX, curriculum checks, checkpoints) on a
# fresh walk run: the whole train path, not just its iteration.
if has chunk; then
  timeout 300 python3 -m biped_switch.train --policy walk --init stand --max-chunks 2 \
    --out /tmp/gpu_runs > "$out/gpu_train_chunks.log" 2>&1; echo "train chunks rc=$?"
  latest=$(ls -d /tmp/gpu_runs/walk_stand/checkpoints/* 2>/dev/null | tail -1)
  [ -n "$latest" ] && cp "$latest/progress.json" "$out/gpu_train_chunks_progress.json"
  grep -v "warp" "$out/gpu_train_chunks.log" | tail -8
fi
for f in "$out"/*.json; do echo "== $f"; cat "$f"; done
for f in "$out"/*.err; do echo "== $f"; tail -5 "$f"; done
