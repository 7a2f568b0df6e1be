"""Train one behaviour policy with PPO (ppo.py) and the guided curriculum, resumable.

    python -m biped_switch.train --policy gaps --init stand [--preset cpu] [--total-steps N]

One env and one compiled PPO iteration serve the whole run (the compile is printed once): the
curriculum's difficulty, guide and push levels enter as traced values. Every `chunk_timesteps`
env steps a whole-episode rollout of the deterministic policy measures the mean reward per step
and the fall rate, `curriculum.update` advances a notch on a milestone (or steps back one when
most episodes fall), and an Orbax checkpoint is written of the
parameters, the optimiser's moments and the observation normaliser, with a `progress.json` (step,
curriculum, evaluation, wall time, speed) beside it. A rerun of the same command resumes from
runs/<policy>_<init>/, or, when that is absent (a fresh clone), from the committed copy under
models/policies/ (`--commit` writes it: the latest checkpoint, config, metrics, curves).
Metrics go to stdout, `metrics.csv` and TensorBoard (`tb/`); the config is saved as `config.json`.
The run folder's layout and files are runs.py's; the config's defaults are config.py's.

    python -m biped_switch.train --policy gaps --init random --probe-guides 0,0.1,0.2,0.3

runs the curriculum check of the latest checkpoint at other guide levels (`probe_guides`): how
tightly the policy leans on the guide level it trained at.

Devices: the envs are split over every local device (pmap; gradients and normaliser statistics
averaged). Multi-host: `--distributed` calls `jax.distributed.initialize()` first, the collectives
then span every process's devices, and only process 0 writes checkpoints and logs (not tested
here: one host).
"""

from __future__ import annotations

import json
import pathlib
import time

import jax
import jax.numpy as jnp
import numpy as np

from biped_switch.learning import curriculum as curr_lib
from biped_switch.simulation import env as env_lib
from biped_switch.learning import ppo
from biped_switch.learning import checkpoints as ckpt_lib
from biped_switch.learning import runs as runs_lib
from biped_switch.config import TRAIN_TRACK_SEED
from biped_switch.names import TRAIN_KINDS  # every behaviour's, kinds outside the paper's too
from biped_switch.paths import rel
from biped_switch.simulation.rollout import rollout, summarize
from biped_switch.simulation.terrain import ARTIFACT_KINDS

# TRAIN_KINDS' "mixed": the end-to-end baseline (Table II's "End-to-end"), one policy trained on
# multi-artifact tracks with the same reward and guided curriculum


def train_env(cfg) -> env_lib.BipedEnv:
    """The training env of a run config (`env.make_env` on tracks TRAIN_TRACK_SEED + seed + i);
    the curriculum's values enter as traced arguments."""
    if cfg.policy not in TRAIN_KINDS:
        raise ValueError(f"unknown policy {cfg.policy!r}; expected one of {TRAIN_KINDS}")
    return env_lib.make_env(cfg.policy, cfg.init, curriculum_cfg=cfg.curriculum,
                            n_tracks=cfg.n_tracks, seed=TRAIN_TRACK_SEED + cfg.seed, **dict(cfg.env))


def milestone_rollout(env, act, rng, eval_cfg, levels) -> dict:
    """The curriculum check's episodes (`rollout`): `eval_cfg.n_envs` of `eval_cfg.horizon_steps`
    at the curriculum's levels (difficulty, guide_scale, push_scale; traced ok)."""
    return rollout(env, act, rng, n_envs=eval_cfg.n_envs, horizon=eval_cfg.horizon_steps,
                   reset_args=dict(zip(("difficulty", "guide_scale", "push_scale"), levels)))


def make_check(env, trainer, eval_cfg):
    """The curriculum check, jitted: (params, norm, rng, levels) -> `milestone_rollout` of the
    deterministic policy (the traced levels never recompile it)."""
    @jax.jit
    def check(params, norm, rng, levels):
        def act(obs, key):
            return trainer.policy(params, norm, obs, key, True)

        return milestone_rollout(env, act, rng, eval_cfg, levels)

    return check


def fell_where(ev: dict) -> str:
    """" (gaps 0.20, flat 0.05)": where the milestone episodes fell, for a stalled curriculum."""
    fell = [f"{k.split('/')[1]} {v:.2f}" for k, v in ev.items() if k.startswith("fell_at/") and v > 0]
    return f" ({', '.join(fell)})" if fell else ""


def met_text(ev: dict) -> str:
    """"; met jumps 0.90, gaps 0.80, stairs 0.70": with more than one kind on the tracks
    (`mixed`), the shares of episodes that reached each kind's detection zone."""
    met = [f"{k} {ev[f'met_{k}']:.2f}" for k in ARTIFACT_KINDS if ev.get(f"met_{k}", 0.0) > 0]
    return f"; met {', '.join(met)}" if len(met) > 1 else ""


def restore(ckpt: pathlib.Path, template: "ppo.TrainState"):
    """(TrainState, progress) of a checkpoint: parameters, optimiser moments and normaliser, in
    the structure of `template` (a fresh `Trainer.init` of the same config)."""
    tree, prog = ckpt_lib.load_checkpoint(ckpt, template)
    return ppo.TrainState(tree["params"], tree["opt_state"], ppo.Normalizer.from_tree(tree["norm"])), prog


def train(cfg, run_dir: pathlib.Path, max_chunks: int | None = None, print_fn=print,
          env_fn=train_env, on_restore=None) -> dict:
    """Trains (or resumes) until `total_timesteps`; returns the last progress record.

    One env (`env_fn(cfg)`) and one compiled PPO iteration serve the whole run: the curriculum's
    difficulty, guide and push levels enter as traced arguments. Every `chunk_timesteps` steps a
    whole-episode rollout of the deterministic policy measures the mean reward per step and the
    fall rate, `curriculum.update` moves a notch (forward on a milestone, back when most fall),
    and a checkpoint is written.
    `on_restore(train_state)` is called with the state a resume restored (a hook for tests).
    One function: the run's loop (resume, chunks, checks, checkpoints) read top to bottom; the
    curriculum's state and end are records of curriculum.py."""
    run_dir.mkdir(parents=True, exist_ok=True)
    runs_lib.restore_committed(run_dir, print_fn)
    writer = jax.process_index() == 0  # multi-host: one process writes
    if writer:
        print_fn = runs_lib.train_log(run_dir, print_fn)
    logger = runs_lib.Logger(run_dir)
    env = env_fn(cfg)
    trainer = ppo.make_train(cfg, env)
    ts = trainer.init(jax.random.PRNGKey(cfg.seed))
    step, wall_s, compile_s = 0, 0.0, None
    fin = curr_lib.CurriculumEnd()  # the curriculum's end and the push plateau (curriculum.py)
    cs = curr_lib.CurriculumState(**cfg.start)
    newest = runs_lib.latest_checkpoint(run_dir)
    restored, ckpt = ckpt_lib.load_newest_intact(run_dir, lambda c: restore(c, ts), print_fn,
                                                 set_aside=writer)
    if ckpt is not None:
        if ckpt != newest:
            print_fn(f"resuming from the newest intact checkpoint, {ckpt}")
        ts, prog = restored
        if on_restore is not None:
            on_restore(ts)
        step, wall_s = prog["step"], prog["wall_s"]
        cs = curr_lib.CurriculumState.from_dict(prog["curriculum"])
        fin = curr_lib.CurriculumEnd.from_progress(prog, lambda: logger.rows(until=step))
        # a resumed run keeps the provenance of its start (the warm-start checkpoint, if any)
        cfg.warm_start = cfg.warm_start or runs_lib.read_config(run_dir).get("warm_start", "")
        logger.drop_after(step)
        print_fn(f"resuming {run_dir} at step {step:,} ({ckpt.name}), curriculum {cs.as_dict()}")
    elif cfg.warm_start:
        ckpt = runs_lib.resolve_checkpoint(cfg.warm_start, run_dir.parent)
        cfg.warm_start = rel(ckpt)  # repo-relative: the same record on every machine
        warm, prog = restore(ckpt, ts)
        ts = ts._replace(params=warm.params, norm=warm.norm)  # fresh optimiser moments
        print_fn(f"warm start from {cfg.warm_start} (step {prog['step']:,})")
    if writer:
        (run_dir / "config.json").write_text(cfg.to_json_best_effort(indent=2))
    if cfg.policy == "walk" and int(cs.stage) == 0:
        # flat tracks: difficulty scales nothing, so the terrain stage is moot
        cs = cs._replace(difficulty=1.0)

    def curr_array(c):
        return jnp.asarray(c.levels(), jnp.float32)

    evaluate = make_check(env, trainer, cfg.eval)
    rng = jax.random.PRNGKey(cfg.seed + 7919 * (step // trainer.steps_per_iteration + 1))
    rng, k = jax.random.split(rng)
    envs = trainer.reset_envs(k, curr_array(cs))
    progress, chunks = {}, 0
    if fin.done and cfg.stop_when_done:
        print_fn(f"[{cfg.policy}/{cfg.init}] the curriculum finished by step {step:,}: nothing to "
                 f"train (--keep-training trains on to --total-steps)")
        return prog
    while step < cfg.total_timesteps and (max_chunks is None or chunks < max_chunks):
        t_chunk, chunk_start = time.perf_counter(), step
        chunk_end = min(step + cfg.chunk_timesteps, cfg.total_timesteps)
        curr = curr_array(cs)
        it, t_log, steps_log, ep_acc = 0, time.perf_counter(), step, {}
        while step < chunk_end:
            rng, k = jax.random.split(rng)
            t0 = time.perf_counter()
            ts, envs, m = trainer.iteration(ts, envs, k, curr)
            if compile_s is None:
                jax.block_until_ready(m)
                compile_s = time.perf_counter() - t0
                print_fn(f"[{cfg.policy}/{cfg.init}] compiled the PPO iteration in {compile_s:.1f} s "
                         f"(once per run; backend {env.backend}, {trainer.steps_per_iteration:,} "
                         f"env steps per iteration)")
                t_log = time.perf_counter()
            step += trainer.steps_per_iteration
            it += 1
            m = {k: float(v) for k, v in jax.device_get(m).items()}
            n_ep = m["episode/count"]
            for k, v in m.items():  # episode means over the log window, weighted by episodes
                if k.startswith("episode/") and k != "episode/count":
                    ep_acc[k] = ep_acc.get(k, 0.0) + v * n_ep
            ep_acc["episode/count"] = ep_acc.get("episode/count", 0.0) + n_ep
            if it % cfg.log_every == 0 or step >= chunk_end:
                ep_n = ep_acc.pop("episode/count")
                m.update({k: v / max(ep_n, 1.0) for k, v in ep_acc.items()})
                m["episode/count"] = ep_n
                if not ep_n:  # no episode ended in the window: no episode statistics to log
                    m = {k: v for k, v in m.items() if not k.startswith("episode/")}
                ep_acc = {}
                now = time.perf_counter()
                sps = (step - steps_log) / max(now - t_log, 1e-9)
                t_log, steps_log = now, step
                left = max(cfg.total_timesteps - step, 0) / max(sps, 1e-9)
                eps = (f"{int(ep_n)} episodes: reward {m['episode/sum_reward']:.1f} length "
                       f"{m['episode/length']:.0f} success {m['episode/success']:.2f}" if ep_n
                       else "no episode ended")
                print_fn(f"[{cfg.policy}/{cfg.init}] step {step:,}  {eps}  stage {curr_lib.STAGES[int(cs.stage)]} "
                         f"d={float(cs.difficulty):.2f} guide={float(cs.guide_scale):.2f} "
                         f"push={float(cs.push_scale):.2f}  {sps:,.0f} steps/s  elapsed "
                         f"{(wall_s + now - t_chunk) / 3600:.2f} h  left ~{left / 3600:.1f} h")
                if writer:
                    logger.log(step, {"train/steps_per_s": sps, **cs._asdict(), **m})
        jax.block_until_ready(ts)
        train_s = time.perf_counter() - t_chunk
        t_eval = time.perf_counter()
        rng, k = jax.random.split(rng)
        ev = summarize(evaluate(ts.params, ts.norm, k, curr), cfg.eval.horizon_steps)
        eval_s = time.perf_counter() - t_eval
        new_cs = curr_lib.update(cs, ev["reward_per_step"], ev["progress_frac"], cfg.curriculum,
                                 fell_frac=ev["fell"])
        new_cs = curr_lib.CurriculumState(*(np.asarray(v).item() for v in new_cs))
        fin, msg = fin.after_check(cs, new_cs, ev, step, cfg.curriculum)
        if msg:
            print_fn(f"[{cfg.policy}/{cfg.init}] {msg}")
        wall_s += train_s + eval_s
        progress = {"step": step, "wall_s": wall_s, "chunk_train_s": train_s, "chunk_eval_s": eval_s,
                    "env_steps_per_s": (step - chunk_start) / train_s, "compile_s": compile_s, "eval": ev,
                    "curriculum_before": cs.as_dict(), "curriculum": new_cs.as_dict(),
                    "backend": env.backend, "device": str(jax.devices()[0]),
                    "n_devices": jax.device_count(), "total_steps": int(cfg.total_timesteps),
                    **fin.as_progress(), "warm_start": cfg.warm_start}
        path = run_dir / "checkpoints" / f"{step:012d}"
        if writer:
            ckpt_lib.save_ppo(run_dir, step, ts, progress)
            logger.log(step, {f"eval/{k}": v for k, v in ev.items()} | {"wall_s": wall_s} | {
                f"curriculum/{k}": v for k, v in new_cs._asdict().items()})
        strike = (f" (fell > regress_fell: strike {int(new_cs.strikes)}/"
                  f"{cfg.curriculum.regress_patience})" if int(new_cs.strikes) else "")
        print_fn(f"[{cfg.policy}/{cfg.init}] chunk done at step {step:,}: eval reward/step "
                 f"{ev['reward_per_step']:.2f}, fell {ev['fell']:.2f}{fell_where(ev)}, success "
                 f"{ev['success']:.2f}, "
                 f"distance {ev['distance_m']:.2f} m{met_text(ev)}; curriculum "
                 f"{cs.as_dict()['stage_name']} "
                 f"d={float(cs.difficulty):.2f} -> {new_cs.as_dict()['stage_name']} "
                 f"d={float(new_cs.difficulty):.2f} guide={float(new_cs.guide_scale):.2f} "
                 f"push={float(new_cs.push_scale):.2f}{strike}; saved {path}")
        if not np.array_equal(curr_array(new_cs), curr_array(cs)):
            # episodes under way were drawn at the old levels: start afresh
            rng, k = jax.random.split(rng)
            envs = trainer.reset_envs(k, curr_array(new_cs))
        cs = new_cs
        chunks += 1
        if fin.done and cfg.stop_when_done:
            print_fn(f"[{cfg.policy}/{cfg.init}] the curriculum finished at step {step:,} "
                     f"({wall_s / 3600:.2f} h): training stops")
            break
    return progress


def probe_guides(run_dir: pathlib.Path, guide_levels, seed: int = 0) -> dict:
    """The curriculum check of a run's latest checkpoint at other guide levels, the
    checkpoint's own difficulty and push level, one rng for all: how tightly a policy is tuned to
    the guide level it trained at, and so whether a check that collapses after a cut fails on the
    level or on the chunk trained after the cut (README, Training)."""
    bad = [g for g in guide_levels if not 0.0 <= float(g) <= 1.0]
    if bad:
        raise ValueError(f"guide levels {bad} are outside [0, 1]")
    run_dir = pathlib.Path(run_dir)
    ckpt = runs_lib.latest_checkpoint(run_dir)
    if ckpt is None:
        raise FileNotFoundError(f"{run_dir}: no checkpoint to probe")
    cfg = runs_lib.run_config(run_dir)
    env = train_env(cfg)
    trainer = ppo.make_train(cfg, env)
    ts, prog = restore(ckpt, trainer.init(jax.random.PRNGKey(cfg.seed)))
    check = make_check(env, trainer, cfg.eval)
    cs = curr_lib.CurriculumState.from_dict(prog.get("curriculum_before", prog["curriculum"]))
    rows = []
    for g in guide_levels:
        levels = jnp.asarray((cs.difficulty, float(g), cs.push_scale), jnp.float32)
        ev = summarize(check(ts.params, ts.norm, jax.random.PRNGKey(seed), levels),
                       cfg.eval.horizon_steps)
        rows.append({"guide_scale": float(g), **{k: ev[k] for k in (
            "fell", "reward_per_step", "distance_m", "success")}})
    return {"checkpoint": str(ckpt), "step": prog["step"], "trained_at": cs.as_dict(),
            "seed": seed, "n_envs": int(cfg.eval.n_envs), "horizon_steps": int(cfg.eval.horizon_steps),
            "rows": rows}


def probe_guides_report(run_dir: pathlib.Path, levels_csv: str, seed: int = 0) -> str:
    """`probe_guides` of a run (its committed copy on a fresh clone) at the comma-separated guide
    levels, written to <run>/probe_guides.json; returns its Markdown."""
    runs_lib.restore_committed(run_dir)
    doc = probe_guides(run_dir, [float(g) for g in levels_csv.split(",")], seed)
    (run_dir / "probe_guides.json").write_text(json.dumps(doc, indent=2))
    return probe_markdown(doc)


def probe_markdown(doc: dict) -> str:
    """A `probe_guides` result as a Markdown table, under a line saying what was probed."""
    c = doc["trained_at"]
    lines = [f"{doc['checkpoint']} (step {doc['step']:,}, trained at difficulty "
             f"{c['difficulty']:g}, guide {c['guide_scale']:.3g}, push {c['push_scale']:.3g}): "
             f"{doc['n_envs']} check episodes of {doc['horizon_steps']} steps, rng seed {doc['seed']}",
             "", "| guide | fell | reward/step | distance m |", "|---|---|---|---|"]
    lines += [f"| {r['guide_scale']:.3g} | {r['fell']:.2f} | {r['reward_per_step']:.2f} | "
              f"{r['distance_m']:.1f} |" for r in doc["rows"]]
    return "\n".join(lines)


def saved_setting(run_dir: pathlib.Path, section: str | None, key: str) -> float | None:
    """A setting a run was last trained with (its config.json under runs/, else the committed
    copy's; None when neither has it; `section` None: a top-level key), so that a resume keeps a
    flag's value (a lowered learning rate, a finer guide notch, its chunk) without repeating it."""
    saved = runs_lib.read_config(run_dir, committed=True)
    v = (saved.get(section, {}) if section else saved).get(key)
    return None if v is None else float(v)
