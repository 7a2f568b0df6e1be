#!/usr/bin/env bash
# `make reproduce`: every row we publish, from the trained policy runs in RUNS, into OUT.
#
# Run it through `make reproduce` (the Makefile sets every variable below, with the full sizes);
# each is required here so that a size is written down in one place. Every command reads its
# policies from RUNS (--runs) and writes its sweeps, lookup tables, model and results under OUT,
# in OUT/results/ laid out as experiments/results/ (lookup/, table1/, table2/, table3/, when/,
# setup/); OUT may not lie under experiments/ or models/.
#
# Each step appends "step<TAB>wall_s<TAB>finished" to OUT/wall_times.tsv and leaves its log in
# OUT/logs/<step>.log and its command in OUT/.done/<step>; a rerun skips a step whose recorded
# command is the same (delete OUT/.done/<step> to redo it), and a sweep resumes from its parts.
# REPRODUCE_DRY_RUN=1 prints "step<TAB>command" for every step instead of running anything
# (tests/test_reproduce.py parses each command with its command line's parser).
set -euo pipefail

for v in PY RUNS OUT TABLE1_INITS CONTEXT_TARGETS PLAIN_POINTS CONTEXT_POINTS WHEN_POINTS_GAPS \
         WHEN_POINTS TRIALS1 TRIALS2 SETUP_EPISODES; do
  if [ -z "${!v:-}" ]; then
    echo "reproduce.sh: $v is not set: run it through \`make reproduce\`" >&2
    exit 2
  fi
done
SWEEP_BATCH=${SWEEP_BATCH:-}  # empty: the config's batch
DRY=${REPRODUCE_DRY_RUN:-}
KINDS="jumps gaps stairs"  # terrain.ARTIFACT_KINDS
REPO=$(cd "$(dirname "$0")/.." && pwd)
RESULTS=$OUT/results

# OUT is this chain's own folder, never one of the committed ones
out_abs=$(realpath -m "$OUT")
for committed in "$REPO/experiments" "$REPO/models"; do
  case "$out_abs/" in
    "$committed"/*) echo "reproduce.sh: OUT=$OUT lies under $committed/: give it a folder of its own" >&2
                    exit 2 ;;
  esac
done
for n in PLAIN_POINTS CONTEXT_POINTS WHEN_POINTS_GAPS WHEN_POINTS TRIALS1 TRIALS2 SETUP_EPISODES; do
  if ! [[ ${!n} =~ ^[1-9][0-9]*$ ]]; then
    echo "reproduce.sh: $n must be a positive integer, got '${!n}'" >&2
    exit 2
  fi
done
for k in $CONTEXT_TARGETS; do
  case " $KINDS " in *" $k "*) ;; *)
    echo "reproduce.sh: CONTEXT_TARGETS: '$k' is not one of: $KINDS" >&2; exit 2 ;; esac
done

# Every policy a step reads must be a run in RUNS: a run missing there would be taken from its
# committed copy under models/policies/ without a word (learning/runs.find_policy).
if [ -z "$DRY" ]; then
  need="walk_stand jumps_stand gaps_stand stairs_stand setup_gaps_stand"
  for init in $TABLE1_INITS; do
    [ "$init" = stand ] || for k in $KINDS; do need="$need ${k}_$init"; done
  done
  for run in $need; do
    if ! compgen -G "$RUNS/$run/checkpoints/*" > /dev/null; then
      echo "reproduce.sh: no checkpoint under $RUNS/$run/checkpoints/: RUNS=$RUNS must hold the" \
           "runs $need" >&2
      exit 2
    fi
  done
  mkdir -p "$OUT/logs" "$OUT/.done"
  [ -f "$OUT/wall_times.tsv" ] || printf 'step\twall_s\tfinished\n' > "$OUT/wall_times.tsv"
fi

# step NAME COMMAND...: runs COMMAND unless it already ran to the end, and records its wall time.
step() {
  local name=$1
  shift
  local cmd
  cmd=$(printf '%q ' "$@")
  cmd=${cmd% }
  if [ -n "$DRY" ]; then
    printf '%s\t%s\n' "$name" "$cmd"
    return
  fi
  local stamp=$OUT/.done/$name
  if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$cmd" ]; then
    echo "reproduce: $name: done before, skipped (delete $stamp to redo it)"
    return
  fi
  echo "reproduce: $name: $cmd"
  local t0=$EPOCHREALTIME
  "$@" 2>&1 | tee "$OUT/logs/$name.log"
  local wall
  wall=$(awk -v a="$t0" -v b="$EPOCHREALTIME" 'BEGIN { printf "%.1f", b - a }')
  printf '%s\t%s\t%s\n' "$name" "$wall" "$(date -Iseconds)" >> "$OUT/wall_times.tsv"
  printf '%s\n' "$cmd" > "$stamp"
  echo "reproduce: $name: $wall s"
}

batch=()
[ -z "$SWEEP_BATCH" ] || batch=(--batch "$SWEEP_BATCH")
plain=()
for k in $KINDS; do
  case " $CONTEXT_TARGETS " in *" $k "*) ;; *) plain+=("$k") ;; esac
done

# 1. Lookup tables (Table II's lookup_context): the context sweep of CONTEXT_TARGETS (committed:
#    gaps, 50,000 points) and, for the other targets, the paper's flat-start sweep (committed:
#    jumps and stairs, 100,000 points), whose entries load_context_lookup takes for the targets
#    the context table lacks. Tables into RESULTS/lookup/, data into OUT/sweeps/.
if [ ${#plain[@]} -gt 0 ]; then
  step sweep_plain "$PY" -m biped_switch.sweep --init stand --targets "${plain[@]}" \
    --points "$PLAIN_POINTS" "${batch[@]}" --runs "$RUNS" --out "$OUT/sweeps" \
    --results "$RESULTS/lookup"
fi
# shellcheck disable=SC2086  # a list of targets
step sweep_context "$PY" -m biped_switch.sweep --init stand --context --targets $CONTEXT_TARGETS \
  --points "$CONTEXT_POINTS" "${batch[@]}" --runs "$RUNS" --out "$OUT/sweeps" \
  --results "$RESULTS/lookup"

# 2. The learned when rule (models/switch_when/README.md's recipe): context sweeps with approach
#    records at U(0.2, 0.9) m into OUT/sweeps_when/ (their lookup table, not used by any row, into
#    RESULTS/lookup_when/, apart from lookup_context's), then the rule into OUT/switch_when/stand
#    and its offline check into RESULTS/when/. The paper's estimators it is scored beside offline
#    are read from models/estimators (the paper's chain, `make reproduce-paper`, makes them).
step sweep_when_gaps "$PY" -m biped_switch.sweep --init stand --context --switch-min 0.2 \
  --targets gaps --points "$WHEN_POINTS_GAPS" "${batch[@]}" --runs "$RUNS" \
  --out "$OUT/sweeps_when" --results "$RESULTS/lookup_when"
step sweep_when_stairs_jumps "$PY" -m biped_switch.sweep --init stand --context --switch-min 0.2 \
  --targets stairs jumps --points "$WHEN_POINTS" "${batch[@]}" --runs "$RUNS" \
  --out "$OUT/sweeps_when" --results "$RESULTS/lookup_when"
step when "$PY" -m biped_switch.when --init stand --data "$OUT/sweeps_when" \
  --out "$OUT/switch_when" --results "$RESULTS/when" --runs "$RUNS"

# 3. The setup policy on held-out two-artifact tracks (seeds 70,000+), beside no setup (the source
#    walks on to the hand-over), tabulated in RESULTS/setup/setup.md.
step setup_gaps "$PY" -m biped_switch.switching.setup eval --full-tracks --target gaps \
  --setup "$RUNS/setup_gaps_stand" --n "$SETUP_EPISODES" --runs "$RUNS" \
  --out "$RESULTS/setup/gaps_setup_gaps.json"
step setup_gaps_source "$PY" -m biped_switch.switching.setup eval --full-tracks --target gaps \
  --setup source --n "$SETUP_EPISODES" --runs "$RUNS" --out "$RESULTS/setup/gaps_source_gaps.json"
step setup_report "$PY" -m biped_switch.reports.setup --results "$RESULTS/setup"

# 4. Table I: each artifact policy on its own terrain (tracks of seeds 10,000+).
# shellcheck disable=SC2086  # a list of inits
step table1 "$PY" -m biped_switch.evaluate single --trials "$TRIALS1" --inits $TABLE1_INITS \
  --runs "$RUNS" --out "$RESULTS/table1"

# 5. Table II, one row per step (rows join in RESULTS/table2/table2.json; tracks of seeds
#    30,000+), each reading the lookup tables and the when rule made above and the setup policy
#    from RUNS.
for method in lookup_context learned lookup_context_setup learned_setup; do
  step "table2_$method" "$PY" -m biped_switch.evaluate multi --methods "$method" \
    --trials "$TRIALS2" --runs "$RUNS" --lookup "$RESULTS/lookup" --when-dir "$OUT/switch_when" \
    --out "$RESULTS/table2"
done

# 6. Table III from the logs: the training runs in RUNS, the sweeps' records in RESULTS/lookup/
#    and the when rule's in OUT/switch_when/.
step table3 "$PY" -m biped_switch.evaluate retrain-cost --runs "$RUNS" --results "$RESULTS" \
  --when-dir "$OUT/switch_when" --out "$RESULTS/table3"

if [ -z "$DRY" ]; then
  echo "reproduce: every step done; wall times [s] in $OUT/wall_times.tsv:"
  cat "$OUT/wall_times.tsv"
fi
