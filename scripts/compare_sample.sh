#!/usr/bin/env bash
# Table I and Table II on a 20-trial sample (every row), written to $1 (default /tmp/sample): run it
# before and after a change that must not change behaviour, then `scripts/compare_sample.py A B`.
set -euo pipefail
out=${1:-/tmp/sample}
export BIPED_SWITCH_NTHREAD=${BIPED_SWITCH_NTHREAD:-1}
py=${PY:-.venv/bin/python}
nice -n 5 $py -m biped_switch.evaluate multi --trials 20 --batch 20 --runs models/policies \
  --fig5-trial -1 --out "$out/t2" --fresh >/dev/null
nice -n 5 $py -m biped_switch.evaluate single --trials 20 --batch 20 --runs models/policies \
  --out "$out/t1" --fresh >/dev/null
echo "$out"
