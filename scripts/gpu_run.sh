#!/usr/bin/env bash
# Run a biped_switch command on the GPU host (no network): installs the carried wheels from .whl/
# (made by `make wheels` here) into /tmp/site, then runs the arguments from the repo root.
#   device run, carry [".whl"]:  bash scripts/gpu_run.sh python3 -m biped_switch.bench --batch 8192 --json
set -euo pipefail
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
  --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:$PWD
exec "$@"
