"""GIF (and contact sheet) of one source -> setup -> target episode of the setup env
(switching/setup.py), the phase written on every frame.

    MUJOCO_GL=osmesa python scripts/render_setup.py --setup runs/setup_gaps_stand --track 0 \
        --out runs/setup_eval/setup_track0.gif

--track is a held-out setup track (setup config eval_track_seed + i; even i: jumps source, odd:
stairs); --setup walk_stand renders walk as the setup policy, --setup source the plain switch.
"""

from __future__ import annotations

import argparse
import pathlib
import sys

from biped_switch.simulation import render as render_lib  # first: sets the GL backend

import jax
import jax.numpy as jnp
import numpy as np


def _label(pic, text):
    from PIL import ImageDraw
    ImageDraw.Draw(pic).text((8, 8), text, fill=(200, 0, 0))
    return pic


def main(argv=None) -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--setup", default="runs/setup_gaps_stand")
    p.add_argument("--target", default="gaps")
    p.add_argument("--track", type=int, default=0)
    p.add_argument("--n-tracks", type=int, default=64)
    p.add_argument("--seconds", type=float, default=16.0)
    p.add_argument("--every", type=int, default=2)
    p.add_argument("--size", default="360x240")
    p.add_argument("--full-tracks", action="store_true",
                   help="full-size artifacts (as `setup eval --full-tracks`)")
    p.add_argument("--eval-batch", type=int, default=1,
                   help="run the track inside the batch `setup eval` ran it in (128: its "
                        "default), since a trajectory depends on the batch's rounding")
    p.add_argument("--out", required=True)
    a = p.parse_args(argv)
    from biped_switch.config import default_setup_config
    from biped_switch.learning import policies as pol
    from biped_switch.learning import runs as runs_lib
    from biped_switch.simulation.rollout import reset_by_track, run_episodes
    from biped_switch.switching import setup as S

    cfg = default_setup_config(a.target)
    if a.full_tracks:
        from biped_switch.config import default_terrain_config
        tc = default_terrain_config(2)
        cfg.setup.source_segments = cfg.setup.target_segments = (tc.segments_min, tc.segments_max)
        cfg.setup.finish_after_m = tc.finish_after_m
    senv = S.make_setup_env(cfg.setup, a.n_tracks, int(cfg.setup.eval_track_seed))
    if a.setup == "source":
        senv.source_in_setup = True
        act = lambda obs, k: jnp.zeros(obs.shape[:-1] + (12,))  # noqa: E731
    else:
        act, _ = pol.load_policy(runs_lib.resolve_checkpoint(a.setup), senv.base)
    horizon = int(round(a.seconds / senv.dt))
    j = a.track % a.eval_batch  # the drawn episode's place in its batch
    soles = jnp.asarray(senv.base.biped.sole_geoms.reshape(-1))

    @jax.jit
    def run(key):
        b0 = a.track // a.eval_batch * a.eval_batch
        ids = jnp.arange(b0, b0 + a.eval_batch, dtype=jnp.int32)
        keys = jax.random.split(jax.random.split(key)[0], a.eval_batch)
        state = reset_by_track(senv, keys, ids)
        ep = run_episodes(senv, state, horizon,
                          lambda c, s, live, k: (act(s.obs, k), c, None), None,
                          trace=lambda c, aux, s, nxt, live: (
                              nxt.pipeline_state.qpos[j], nxt.info["phase"][j],
                              nxt.pipeline_state.geom_xpos[j][soles], nxt.obs[j][24:32]),
                          rng=jax.random.PRNGKey(1))
        return state.pipeline_state.qpos[j], state.info["boxes"][j], ep

    q0, boxes, ep = jax.device_get(run(jax.random.PRNGKey(0)))
    n = int(ep.length[j])
    qpos = np.concatenate([q0[None], np.asarray(ep.trace[0])[:n]])
    phase = np.concatenate([[S.SOURCE], np.asarray(ep.trace[1])[:n]])
    m = {k: float(v[j]) for k, v in ep.metrics.items()}
    # foot slip: horizontal speed of sole points that touch at two control steps in a row, per
    # phase of the first of the two (a setup policy that slides would show it here)
    sx, con = np.asarray(ep.trace[2])[:n], np.asarray(ep.trace[3])[:n] > 0.5
    both = con[1:] & con[:-1]
    v = np.linalg.norm(sx[1:, :, :2] - sx[:-1, :, :2], axis=-1) / senv.dt
    ph = np.asarray(ep.trace[1])[:n][:-1]
    for k, name in enumerate(S.PHASES):
        sel = both & (ph == k)[:, None]
        if sel.any():
            print(f"{name}: mean slip of touching sole points {v[sel].mean():.3f} m/s, "
                  f"95th pct {np.percentile(v[sel], 95):.3f} m/s ({int(sel.sum())} samples)")
    w, h = (int(x) for x in a.size.split("x"))
    images = render_lib.frames(qpos, np.asarray(boxes), w, h, a.every)
    from PIL import Image, ImageDraw
    out_imgs = []
    for im, ph in zip(images, phase[::a.every]):
        pic = Image.fromarray(im)
        ImageDraw.Draw(pic).text((8, 8), S.PHASES[int(ph)].upper(), fill=(200, 0, 0))
        out_imgs.append(np.asarray(pic))
    out = pathlib.Path(a.out)
    render_lib.write(out_imgs, out, fps=1.0 / (senv.dt * a.every), colors=64)
    render_lib.contact_sheet(out_imgs, out.with_suffix(".png"))
    # the setup phase up close: every control step from 5 before it to 10 after the hand-over
    idx = np.flatnonzero(phase == S.SETUP)
    if idx.size:
        lo, hi = max(idx[0] - 5, 0), min(idx[-1] + 11, len(qpos))
        close = render_lib.frames(qpos[lo:hi], np.asarray(boxes), w, h, 1)
        close = [np.asarray(_label(Image.fromarray(im), S.PHASES[int(ph)].upper()))
                 for im, ph in zip(close, phase[lo:hi])]
        render_lib.contact_sheet(close, out.with_name(out.stem + "_setup.png"), n=len(close),
                                 cols=8)
    src = senv.names[int(m["source"])]
    print(f"track {a.track} ({src} -> {a.target}): {'success' if m['success'] > 0.5 else 'FELL' if m['fell'] > 0.5 else 'timeout'} "
          f"after {n} steps, setup steps {int(m['setup_steps'])}; {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
