"""Switch estimators (paper Sec. III-C): when is the robot in the target policy's region of attraction?

The command line of `biped_switch.switching.estimator`: `python -m biped_switch.estimator` or `biped-switch estimator`.
"""

from __future__ import annotations

import argparse
import functools
import json
import pathlib
import sys
from biped_switch import cli
from biped_switch.config import default_estimator_config
from biped_switch.simulation.env import STATE_SIZE
from biped_switch.switching import estimator as estimator_lib
from biped_switch.reports.estimators import plot_history


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m biped_switch.estimator", description=__doc__.split("\n")[0])
    cli.add_init(p)
    p.add_argument("--targets", nargs="+", default=list(estimator_lib.TARGETS), choices=estimator_lib.TARGETS)
    p.add_argument("--data", default="runs/sweeps", help="sweep data: DATA/<init>/<target>.npz")
    cli.add_out(p, "models/estimators", "one checkpoint folder per estimator, <init>_<target>/")
    p.add_argument("--results", default="experiments/results/estimators",
                   help="metrics JSON, history CSV and curves PNG: RESULTS/<init>_<target>.*")
    p.add_argument("--epochs", type=cli.positive_int, default=None)
    p.add_argument("--batch-size", type=cli.positive_int, default=None)
    p.add_argument("--seed", type=cli.nonneg_int, default=None)
    p.add_argument("--log-every", type=cli.positive_int, default=50, help="progress line every N epochs")
    p.add_argument("--context", action="store_true",
                   help="train on the context sweep (`sweep --context`: DATA/<init>_context/); "
                        "checkpoints and results are named <init>_context_<target>")
    a = p.parse_args(argv)
    name = estimator_lib.sweep_name(a.init, a.context)

    cfg = default_estimator_config()
    for k in ("epochs", "batch_size", "seed"):
        if getattr(a, k) is not None:
            cfg[k] = getattr(a, k)
    files = {t: pathlib.Path(a.data) / name / f"{t}.npz" for t in a.targets}
    missing = [t for t, f in files.items() if not f.exists()]
    if missing:
        for t in missing:
            print(f"error: missing sweep data {files[t]}; make it with "
                  f"`python -m biped_switch.sweep --init {a.init} --targets {t}"
                  f"{' --context' if a.context else ''}`", file=sys.stderr)
        return 2
    results = pathlib.Path(a.results)
    results.mkdir(parents=True, exist_ok=True)
    log = functools.partial(print, flush=True)
    rows = []
    for t, f in files.items():
        data = estimator_lib.load_data(f)
        params, metrics = estimator_lib.train_estimator(data, cfg, print_fn=log, log_every=a.log_every,
                                          name=f"{name}/{t}")
        history = metrics.pop("history")
        meta = {"target": t, "init": a.init, "context": a.context, "data_file": str(f),
                "config": cfg.to_dict(),
                "metrics": metrics, "sweep_meta": data.get("meta"),
                "input": {"state_size": STATE_SIZE, "hm_size": estimator_lib.HM_SIZE}}
        ckpt = estimator_lib.save_estimator(pathlib.Path(a.out) / f"{name}_{t}", params, meta)
        stem = results / f"{name}_{t}"
        (stem.with_suffix(".json")).write_text(json.dumps(
            {k: v for k, v in meta.items() if k != "sweep_meta"} | {"checkpoint": str(ckpt)},
            indent=2, default=estimator_lib.jsonable))
        with stem.with_name(stem.name + "_history.csv").open("w") as fh:
            fh.write("epoch," + ",".join(history) + "\n")
            for i, row in enumerate(zip(*history.values()), 1):
                fh.write(f"{i}," + ",".join(f"{v:.6g}" for v in row) + "\n")
        plot_history(history, stem.with_suffix(".png"), f"switch estimator {name}/{t}")
        log(f"[{name}/{t}] val acc {metrics['val_acc']:.3f}  AUC {metrics['val_auc']:.3f}  "
            f"saved {ckpt}")
        rows.append((t, metrics))
    log(f"\nswitch estimators, {name}:\n"
        "| target | points (train / val) | val acc | val AUC | train s |\n|---|---|---|---|---|")
    for t, m in rows:
        log(f"| {t} | {m['points_total']:,} ({m['train_points']:,} / {m['val_points']:,}) | "
            f"{m['val_acc']:.3f} | {m['val_auc']:.3f} | {m['train_s']:.0f} |")
    return 0


if __name__ == "__main__":
    from biped_switch.cli import run

    run(main)
