# biped_switch: `make demo` (the main job) and `make test` (the tests) each install what they need
# into .venv by themselves on a fresh machine (Python 3.11+ and PyPI access).
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: reproduce reproduce-paper install demo docs notebooks test test-all test-deps bench bench-train bench-estimator bench-1art train train-all render-deps wheels clean train-estimators train-dqn

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]'
	touch $@

install: $(STAMP)

demo: $(STAMP)
	@$(MAKE) -s render-deps || echo "demo: could not install OSMesa (needs apt as root): no video"
	$(PY) -m biped_switch.demo

# docs/results.md from the committed result files (experiments/results/**): run it after a command
# rewrites one; tests/test_results_doc.py fails while the page is stale.
docs: $(STAMP)
	$(PY) -m biped_switch.reports.results

# The notebooks executed on the committed results and saved with their outputs (tables, figures).
notebooks: $(STAMP)
	$(PY) scripts/run_notebooks.py

# Two workers (pytest-xdist), one test file each at a time so module fixtures compile once per
# worker: 8 min instead of 9 on a 2-core machine, where compiling MJX dominates.
# Both install the offscreen renderer first (render-deps): tests/test_render.py draws frames and
# fails without one. BIPED_SWITCH_SKIP_RENDER=1 skips the install and that test (a machine without
# root). The old name, BIPED_SKIP_RENDER, still works for now (deprecated: every variable of the
# project is BIPED_SWITCH_*).
BIPED_SWITCH_SKIP_RENDER ?= $(BIPED_SKIP_RENDER)
export BIPED_SWITCH_SKIP_RENDER
test: $(STAMP) test-deps
	$(PY) -m pytest -q -n 2 --dist loadfile

test-all: $(STAMP) test-deps  ## includes tests marked slow
	$(PY) -m pytest -q -n 2 --dist loadfile -m ''

test-deps:
	@if [ -n "$$BIPED_SKIP_RENDER" ]; then \
	  echo "BIPED_SKIP_RENDER is deprecated: set BIPED_SWITCH_SKIP_RENDER=1 instead" >&2; fi
	@if [ "$$BIPED_SWITCH_SKIP_RENDER" = 1 ]; then \
	  echo "BIPED_SWITCH_SKIP_RENDER=1: no renderer installed, tests/test_render.py skips its drawing test"; \
	else $(MAKE) -s render-deps; fi

bench: $(STAMP)
	$(PY) -m biped_switch.bench --batch 256 --kind mixed --json

bench-train: $(STAMP)  ## PPO env steps/s on mixed tracks, and its ratio to the raw physics rate
	$(PY) -m biped_switch.bench --train --kind mixed --json

bench-estimator: $(STAMP)  ## switch-estimator training speed (first epoch compiles, then steady epochs)
	$(PY) -m biped_switch.bench --estimator --points 100000 --epochs 3 --json

bench-1art: $(STAMP)  ## same, on 1-artifact tracks (cost must not grow with track length)
	$(PY) -m biped_switch.bench --batch 256 --kind mixed --n-artifacts 1 --json

# Policies. TRAIN_ARGS e.g. "--total-steps 20000000"; the preset follows the platform (cpu/gpu).
# Each run resumes from its last checkpoint under runs/<policy>_<init>/, or from the committed
# models/policies/<policy>_<init>/ on a fresh clone.
POLICY ?= walk
INIT   ?= stand
TRAIN_ARGS ?=
train: $(STAMP)
	$(PY) -m biped_switch.train --policy $(POLICY) --init $(INIT) $(TRAIN_ARGS)

# The whole suite from scratch, each committed run by its recipe (models/policies/<run>/recipe.json:
# its flags, every mid-run change with its step and reason, its warm start; learning/recipe.py),
# warm-start sources first, into runs/replay/<run>/ (a rerun resumes; `evaluate --runs runs/replay`
# reads the result). RECIPES picks runs, e.g. RECIPES=models/policies/walk_stand. The DQN's recipes
# replay the same way: `python -m biped_switch.train --recipe models/baselines/dqn_stand`.
# SEED=1: a second training seed of the recipes, into runs/replay_seed1/ (sources: its own replays).
# JOBS=3: up to three replays at a time, one mujoco thread each, a recipe starting once its
# sources have replayed far enough (the artifact policies side by side after walk's 32.37M).
RECIPES ?= models/policies/*/
SEED ?=
JOBS ?= 1
train-all: $(STAMP)
	$(PY) -m biped_switch.train --recipe $(RECIPES) $(if $(SEED),--seed $(SEED)) --jobs $(JOBS)

# Offscreen rendering on a CPU host: OSMesa (Debian's libosmesa6), installed with apt (as root)
# unless already there (then this returns at once). A GPU host uses EGL.
render-deps:
	@if [ -e /dev/nvidia0 ] || ldconfig -p 2>/dev/null | grep -q libOSMesa; then :; else \
	  export DEBIAN_FRONTEND=noninteractive; apt-get install -y -q libosmesa6 || \
	  (apt-get update -q && apt-get install -y -q libosmesa6) || \
	  { echo "render-deps: could not install libosmesa6 (needs apt as root); set BIPED_SWITCH_SKIP_RENDER=1 to test without rendering" >&2; exit 1; }; fi

# Wheels for the GPU host (Python 3.12, jax 0.11.2, flax/optax/orbax preinstalled, no network):
# everything else it needs, into the git-ignored .whl/ (about 30 MB). See scripts/gpu_run.sh.
GPU_WHEELS := mujoco==4.0.0 mujoco-core==4.0.0 mujoco-studio==4.0.0 mujoco-mjx==3.17.0 \
  brax==0.14.2 ml-collections==1.1.0 jaxopt==0.8.5 trimesh==5.2.0 tensorboardx==2.6.5 \
  glfw==2.11.0 pyopengl==3.1.10 flask==3.1.3 flask-cors==6.0.5 itsdangerous==2.2.0 blinker==1.9.0
PLATFORMS := $(foreach n,2_28 2_27 2_17,--platform manylinux_$(n)_x86_64) --platform manylinux2014_x86_64 \
  --platform manylinux1_x86_64 --platform any
wheels:
	mkdir -p .whl
	$(PYTHON) -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 \
	  --implementation cp $(PLATFORMS) -d .whl $(GPU_WHEELS)
	du -sh .whl

clean:
	rm -rf $(VENV) .pytest_cache *.egg-info

# Switch estimators (paper Sec. III-C), one per target policy, from the sweeps' runs/sweeps/<init>/<target>.npz
# (made by `python -m biped_switch.sweep`). ESTIMATOR_ARGS e.g. "--epochs 100".
ESTIMATOR_ARGS ?=
train-estimators: $(STAMP)
	$(PY) -m biped_switch.estimator --init stand $(ESTIMATOR_ARGS)
	$(PY) -m biped_switch.estimator --init random $(ESTIMATOR_ARGS)

# DQN selector baseline (paper Sec. IV-C), on mixed tracks over the stand-init policy suite; resumes
# from runs/dqn_stand/, else from its committed copy models/baselines/dqn_stand/ (`--commit` writes
# it). The preset follows the platform (cpu: 64 envs, 10M env steps; gpu: 512 envs, 20M).
DQN_ARGS ?=
train-dqn: $(STAMP)
	$(PY) -m biped_switch.dqn $(DQN_ARGS)

# Every row we publish, from a folder of trained policy runs RUNS (e.g. runs/replay_seed1 of
# `make train-all SEED=1`: walk, jumps, gaps, stairs and setup_gaps, stand init) into a results
# folder of its own, OUT (never experiments/results/ or models/; OUT/results/ is laid out as
# experiments/results/). scripts/reproduce.sh runs, each command with --runs $(RUNS):
#  1. the lookup tables: the context sweep of CONTEXT_TARGETS (committed: gaps, 50,000 points) and
#     the flat-start sweep of the other targets (jumps and stairs, 100,000 points each), whose
#     entries lookup_context takes where the context table has none;
#  2. the learned when rule: context sweeps with approach records (--switch-min 0.2; gaps 40,000,
#     stairs and jumps 25,000 points), then `when` into OUT/switch_when/;
#  3. the setup policy's evaluation (512 held-out tracks, with and without setup_gaps);
#  4. Table I (500 trials, tracks 10,000+, TABLE1_INITS); 5. Table II rows lookup_context, learned,
#     lookup_context_setup and learned_setup (2,500 trials, tracks 30,000+), read from OUT's lookup
#     tables and when rule and RUNS' setup policy; 6. Table III from the logs.
# Each step's wall time goes to OUT/wall_times.tsv (its log to OUT/logs/); a rerun skips the steps
# that finished with the same command, and sweeps resume from their parts. The sizes are the
# committed rows'; a quick check of the chain, e.g. `make reproduce RUNS=models/policies
# OUT=/tmp/repro SWEEP_POINTS=300 SWEEP_BATCH=32 TRIALS1=8 TRIALS2=8 SETUP_EPISODES=8`.
RUNS ?= runs/replay_seed1
OUT ?= runs/reproduce/$(notdir $(patsubst %/,%,$(RUNS)))
SWEEP_POINTS ?=# set: every sweep makes this many points per target (in place of the sizes below)
PLAIN_POINTS ?= $(or $(SWEEP_POINTS),100000)
CONTEXT_POINTS ?= $(or $(SWEEP_POINTS),50000)
WHEN_POINTS_GAPS ?= $(or $(SWEEP_POINTS),40000)
WHEN_POINTS ?= $(or $(SWEEP_POINTS),25000)
SWEEP_BATCH ?=# episodes per jitted sweep batch (empty: the config's)
CONTEXT_TARGETS ?= gaps
TABLE1_INITS ?= stand
TRIALS1 ?= 500
TRIALS2 ?= 2500
SETUP_EPISODES ?= 512
reproduce: $(STAMP)
	PY=$(PY) RUNS='$(RUNS)' OUT='$(OUT)' SWEEP_BATCH='$(SWEEP_BATCH)' \
	  CONTEXT_TARGETS='$(CONTEXT_TARGETS)' TABLE1_INITS='$(TABLE1_INITS)' \
	  PLAIN_POINTS='$(PLAIN_POINTS)' CONTEXT_POINTS='$(CONTEXT_POINTS)' \
	  WHEN_POINTS_GAPS='$(WHEN_POINTS_GAPS)' WHEN_POINTS='$(WHEN_POINTS)' TRIALS1='$(TRIALS1)' \
	  TRIALS2='$(TRIALS2)' SETUP_EPISODES='$(SETUP_EPISODES)' bash scripts/reproduce.sh

# The paper's results at full size, from trained policies (make train-all first; a GPU host):
# sweeps + lookup tables, estimators, the DQN, Table I, Table II (2,500 trials, 8 methods), Table III.
# Sweeps and training runs resume from their saved parts and checkpoints. It writes into the
# committed folders (experiments/results/, models/).
reproduce-paper: $(STAMP)
	$(PY) -m biped_switch.sweep --init stand
	$(PY) -m biped_switch.sweep --init random
	$(MAKE) train-estimators train-dqn
	$(PY) -m biped_switch.train --policy mixed --init stand --guide-notch 0.25 $(TRAIN_ARGS)
	$(PY) -m biped_switch.evaluate single --trials 500
	$(PY) -m biped_switch.evaluate multi --trials 2500
	$(PY) -m biped_switch.evaluate retrain-cost
