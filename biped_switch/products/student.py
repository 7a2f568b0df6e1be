"""The body of `distill` (biped_switch/distill.py parses its flags): the composed controller as a
frozen teacher, and the DAgger run that distils it into one student policy
(learning/distillation.py), resumable from its checkpoints.

The teacher is a Table II row run exactly as `evaluate multi` runs it (its MultiSetup: the policy
suite with its setup policies, its lookup table, the oracle detector), on the student's training
tracks (STUDENT_TRACK_SEED + seed + i, mixed, 7 artifacts). The run folder holds config.json,
metrics.csv, train.log, checkpoints/<step>/ (the PPO layout, so the student loads as a policy)
and buffer.npz, the aggregate dataset of the newest checkpoint (not committed: a resume without
it starts an empty buffer and says so).
"""

from __future__ import annotations

import pathlib
import time

import jax
import jax.numpy as jnp
import numpy as np

from biped_switch.config import STUDENT_TRACK_SEED
from biped_switch.evaluation.multi import MultiConfig, MultiSetup
from biped_switch.learning import checkpoints as ckpt_lib
from biped_switch.learning import distillation as dist
from biped_switch.learning import runs as runs_lib
from biped_switch.learning.normalizer import Normalizer
from biped_switch.learning.policies import load_policy
from biped_switch.methods import method as method_record
from biped_switch.simulation.rollout import reset_by_track, run_episodes
from biped_switch.switching import rules as sw

BUFFER_FILE = "buffer.npz"
# the iteration's metrics that are means over the episodes it ended
EPISODE_MEANS = ("episode/success", "episode/fell", "episode/progress_frac")


def teacher_setup(cfg) -> MultiSetup:
    """The MultiSetup of the teacher row `cfg.distill.teacher` on the student's training tracks."""
    rec = method_record(cfg.distill.teacher)
    if rec.baseline:
        raise ValueError(f"distill.teacher {rec.name!r} is a baseline; the teacher is a switching "
                         f"row (e.g. lookup_context_setup)")
    mc = MultiConfig(trials=int(cfg.n_tracks), batch=int(cfg.distill.num_envs),
                     horizon_s=float(cfg.distill.horizon_s), runs=str(cfg.distill.teacher_runs),
                     track_seed=STUDENT_TRACK_SEED + int(cfg.seed), backend=cfg.env.backend)
    return MultiSetup([rec], mc)


def make_teacher(setup: MultiSetup, method: str) -> dist.Teacher:
    """Row `method`'s controller as a dist.Teacher: the action of the policy it has active, its
    switching state carried per env (`rules.switch_and_act`, as Table II steps it)."""
    rules, est_params = setup.rules_for(method)
    act = sw.switch_and_act(setup.env, setup.suite.apply, setup.suite.params, setup.est_apply,
                            est_params, rules, setup.det_apply, setup.det_params)

    def teacher_act(ss, state, key):
        n = state.obs.shape[0]
        action, ss, _, _ = act(ss, state, jnp.ones(n, bool), jax.random.uniform(key, (n,)))
        return action, ss, ss.active

    return dist.Teacher(sw.init_state, teacher_act, len(setup.policy_names))


def _restore(ckpt: pathlib.Path, template: dist.DaggerState, log_std: float):
    """(DaggerState without its buffer, progress) of a student checkpoint, in `template`'s shapes."""
    item = dist.checkpoint_tree(template, log_std)
    tree, prog = ckpt_lib.read_tree(ckpt, item), runs_lib.read_progress(ckpt)
    return template._replace(params={"policy": tree["params"]["policy"]},
                             opt_state=tree["opt_state"],
                             norm=Normalizer.from_tree(tree["norm"])), prog


def save_buffer(run_dir: pathlib.Path, step: int, buf: dist.Buffer) -> None:
    """The aggregate dataset beside the checkpoint of `step` (written whole, then renamed)."""
    tmp = run_dir / (BUFFER_FILE + ".tmp.npz")
    np.savez(tmp, step=np.int64(step), **dist.buffer_arrays(buf))
    tmp.replace(run_dir / BUFFER_FILE)


def load_buffer(run_dir: pathlib.Path, step: int, template: dist.Buffer, print_fn=print):
    """The buffer saved with the checkpoint of `step`, else `template` (empty) with a line why."""
    path = run_dir / BUFFER_FILE
    if not path.exists():
        print_fn(f"no {BUFFER_FILE} in {run_dir}: the aggregate dataset starts empty")
        return template
    with np.load(path) as f:
        if int(f["step"]) != step:
            print_fn(f"{path} is of step {int(f['step']):,}, the checkpoint of {step:,}: the "
                     f"aggregate dataset starts empty")
            return template
        return dist.buffer_from_arrays(template, f["x"], f["y"])


def train(cfg, run_dir: pathlib.Path, max_chunks: int | None = None, print_fn=print) -> dict:
    """Distils (or resumes distilling) to `cfg.distill.total_env_steps`; returns the last progress
    record. One compiled DAgger iteration serves the whole run; the teacher's mixing probability
    enters it as a traced scalar, from the env step (`distillation.mix_at`)."""
    d = cfg.distill
    run_dir.mkdir(parents=True, exist_ok=True)
    runs_lib.restore_committed(run_dir, print_fn)
    print_fn = runs_lib.train_log(run_dir, print_fn)
    logger = runs_lib.Logger(run_dir)
    t_setup = time.perf_counter()
    setup = teacher_setup(cfg)
    teacher = make_teacher(setup, d.teacher)
    print_fn(f"[student] teacher {d.teacher}: {len(setup.policy_names)} policies "
             f"{list(setup.policy_names)} on {cfg.n_tracks} mixed tracks from "
             f"{STUDENT_TRACK_SEED + int(cfg.seed):,} ({time.perf_counter() - t_setup:.0f} s)")
    for src in setup.suite.sources:
        print_fn(f"[student]   {src}")
    cfg.env.update(setup.suite.env_overrides)  # what the student acts in: the suite's env
    dag = dist.make_dagger(cfg, setup.env, teacher)
    ds = dag.init(jax.random.PRNGKey(cfg.seed))
    step, wall_s, compile_s = 0, 0.0, None
    restored, ckpt = ckpt_lib.load_newest_intact(
        run_dir, lambda c: _restore(c, ds, float(d.log_std)), print_fn, set_aside=True)
    if ckpt is not None:
        (ds, prog) = restored
        step, wall_s = int(prog["step"]), float(prog["wall_s"])
        ds = ds._replace(buffer=load_buffer(run_dir, step, ds.buffer, print_fn))
        logger.drop_after(step)
        print_fn(f"[student] resuming {run_dir} at step {step:,} ({ckpt.name}), buffer "
                 f"{int(ds.buffer.count):,} rows")
    (run_dir / "config.json").write_text(cfg.to_json_best_effort(indent=2))
    spi = dag.steps_per_iteration
    rng = jax.random.PRNGKey(cfg.seed + 7919 * (step // spi + 1))
    rng, k = jax.random.split(rng)
    # committed to the device, as the iteration's outputs are: a restored tree otherwise differs
    # from them in sharding only, and the second iteration would compile again
    ds, envs = jax.device_put((ds, dag.reset_envs(k)), jax.devices()[0])
    total, progress, chunks = int(d.total_env_steps), {}, 0
    while step < total and (max_chunks is None or chunks < max_chunks):
        t_chunk, chunk_start = time.perf_counter(), step
        chunk_end = min(step + int(d.chunk_env_steps), total)
        it, t_log, steps_log, acc = 0, time.perf_counter(), step, {}
        while step < chunk_end:
            mix = dist.mix_at(step, float(d.mix_start), float(d.mix_end), int(d.mix_decay_steps))
            rng, k = jax.random.split(rng)
            t0 = time.perf_counter()
            ds, envs, m = dag.iteration(ds, envs, k, jnp.float32(mix))
            if compile_s is None:
                jax.block_until_ready(m)
                compile_s = time.perf_counter() - t0
                print_fn(f"[student] compiled the DAgger iteration in {compile_s:.1f} s (backend "
                         f"{setup.env.backend}, {spi:,} env steps per iteration)")
                t_log = time.perf_counter()
            step += spi
            it += 1
            m = {k: float(v) for k, v in jax.device_get(m).items()}
            # over the log window: episode means weighted by episodes ended, the rest per iteration
            weight = {k: m["episode/count"] if k in EPISODE_MEANS else 1.0 for k in m}
            for k, v in m.items():
                acc[k] = acc.get(k, 0.0) + v * weight[k]
            if it % int(d.log_every) == 0 or step >= chunk_end:
                n_ep = acc["episode/count"]
                row = {k: v / (max(n_ep, 1.0) if k in EPISODE_MEANS else 1.0 if k == "episode/count"
                               else it) for k, v in acc.items()}
                acc, it = {}, 0
                now = time.perf_counter()
                sps = (step - steps_log) / max(now - t_log, 1e-9)
                t_log, steps_log = now, step
                eps = (f"{int(n_ep)} episodes: success {row['episode/success']:.2f} fell "
                       f"{row['episode/fell']:.2f} progress {row['episode/progress_frac']:.2f}"
                       if n_ep else "no episode ended")
                print_fn(f"[student] step {step:,}  mix {row['dagger/mix']:.2f}  mse "
                         f"{row['loss/action_mse']:.4f} (on-policy {row['dagger/onpolicy_mse']:.4f})"
                         f"  {eps}  {sps:,.0f} steps/s  elapsed "
                         f"{(wall_s + now - t_chunk) / 3600:.2f} h  left "
                         f"~{max(total - step, 0) / max(sps, 1e-9) / 3600:.1f} h")
                logger.log(step, {"train/steps_per_s": sps, **row})
        jax.block_until_ready(ds)
        train_s = time.perf_counter() - t_chunk
        wall_s += train_s
        progress = {"step": step, "wall_s": wall_s, "chunk_train_s": train_s,
                    "env_steps_per_s": (step - chunk_start) / train_s, "compile_s": compile_s,
                    "samples_labelled": step, "buffer_rows": int(ds.buffer.count),
                    "mix": mix,
                    "teacher": d.teacher, "teacher_policies": list(setup.suite.sources),
                    # no curriculum: Table II's conditions throughout
                    "curriculum": {"stage_name": "distillation", "difficulty": 1.0,
                                   "guide_scale": 0.0, "push_scale": 0.0},
                    "backend": setup.env.backend, "device": str(jax.devices()[0]),
                    "total_steps": total}
        path = ckpt_lib.save_tree(run_dir, step, dist.checkpoint_tree(ds, float(d.log_std)),
                                  progress, keep=2)
        save_buffer(run_dir, step, ds.buffer)
        logger.log(step, {"wall_s": wall_s})
        print_fn(f"[student] chunk done at step {step:,} ({wall_s / 3600:.2f} h); saved {path}")
        chunks += 1
    return progress


def trace_trial(cfg, student_ckpt: pathlib.Path, trial: int, track_seed: int, seed: int = 0) -> dict:
    """Per-step record of the student on one Table II-style trial (mixed track track_seed +
    trial, walk start, 60 s horizon), with the teacher's controller carried along the student's
    own trajectory: which policy it has active and the action it would take. For the
    Fig. 5-style drawing (reports/student.py) and the GIF."""
    rec = method_record(cfg.distill.teacher)
    mc = MultiConfig(trials=trial + 1, batch=1, horizon_s=float(cfg.distill.horizon_s),
                     runs=str(cfg.distill.teacher_runs), track_seed=track_seed,
                     backend=cfg.env.backend)
    setup = MultiSetup([rec], mc)
    env, teacher = setup.env, make_teacher(setup, rec.name)
    act_student, _ = load_policy(pathlib.Path(student_ckpt), env)

    def act(ts, state, live, key):
        label, ts, active = teacher.act(ts, state, key)
        action = act_student(state.obs, None)
        return action, ts, (action, label, active)

    def trace(ts, aux, state, nxt, live):
        action, label, active = aux
        si = jax.vmap(env.switch_inputs)(state)
        return {"time_s": state.info["time_s"][0], "qpos": state.pipeline_state.qpos[0],
                "com_x_m": si["com_x_m"][0], "det_kind": si["detect"]["kind"][0],
                "det_dist_m": si["detect"]["dist_m"][0], "active": active[0],
                "student": action[0], "teacher": label[0],
                "ended": (~live[0]).astype(jnp.float32), "fell": nxt.metrics["fell"][0],
                "success": nxt.metrics["success"][0]}

    @jax.jit
    def run(rng):
        state = reset_by_track(env, rng[None], jnp.asarray([trial], jnp.int32), guide_scale=0.0)
        return run_episodes(env, state, setup.horizon, act, teacher.init(1), trace=trace,
                            rng=rng, freeze_state=True).trace

    out = {k: np.asarray(v) for k, v in jax.device_get(run(jax.random.PRNGKey(seed + trial))).items()}
    out["policy_names"] = np.asarray(setup.policy_names)
    out["boxes"] = np.asarray(env.track_arrays(trial, 1.0)[0])
    out["track_seed"] = np.int64(track_seed + trial)
    return out


def draw_trial(cfg, run_dir: pathlib.Path, trial: int, track_seed: int, out: pathlib.Path,
               gif_every: int = 6) -> list[pathlib.Path]:
    """The student run's latest checkpoint on one trial: trace_trial's record (npz), its drawing
    (reports/student.py) and a GIF (every `gif_every`-th control step, in real time), into `out`."""
    from biped_switch.evaluation.multi import mixed_track
    from biped_switch.reports import student as report
    from biped_switch.simulation import render

    ckpt = runs_lib.latest_checkpoint(run_dir) or runs_lib.find_policy("student", "stand", run_dir.parent)
    if ckpt is None:
        raise FileNotFoundError(f"no student checkpoint in {run_dir} (python -m biped_switch.distill)")
    rec = trace_trial(cfg, ckpt, trial, track_seed)
    out.mkdir(parents=True, exist_ok=True)
    stem = out / f"student_trial{track_seed + trial}"
    np.savez_compressed(stem.with_suffix(".npz"), **rec)
    track = mixed_track(track_seed + trial)
    title = f"student {runs_lib.read_progress(ckpt)['step']:,} env steps ({ckpt})"
    report.plot_trace(rec, track, stem.with_suffix(".png"), title)
    live = int(np.sum(rec["ended"] < 0.5))
    images = render.frames(rec["qpos"][:max(live, 2)], rec["boxes"], width=320, height=240,
                           every=gif_every)
    dt = float(np.median(np.diff(rec["time_s"][:max(live, 2)])))  # the control period [s]
    render.write(images, stem.with_suffix(".gif"), fps=1.0 / (gif_every * dt))
    return [stem.with_suffix(s) for s in (".npz", ".png", ".gif")]
