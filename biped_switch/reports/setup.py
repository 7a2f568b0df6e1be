"""Setup policies measured on held-out two-artifact tracks (`python -m biped_switch.switching.setup
eval --out experiments/results/setup/<name>.json`), as one Markdown table per target. Plain
Python, no JAX.

    python -m biped_switch.reports.setup [--results experiments/results/setup]   # writes setup.md
"""

from __future__ import annotations

import json
import pathlib


def _who(doc: dict) -> str:
    """What acted in the setup phase of an evaluation."""
    spec = str(doc["setup_policy"])
    if spec == "source":
        return "no setup: the source walks on to the hand-over"
    step = doc.get("setup_policy_step")
    return f"{_run_name(spec)} at {step / 1e6:.2f}M env steps" if step is not None else spec


def _run_name(spec: str) -> str:
    """The run a checkpoint path belongs to (<policy>_<init>; a copy's folder may add a suffix)."""
    for part in reversed(pathlib.PurePath(spec).parts):
        for init in ("_stand", "_random"):
            if init in part:
                return part[:part.index(init) + len(init)]
    return spec


def setup_markdown(docs: list[dict]) -> str:
    """One table per target: rows = what acted in the setup phase, columns = source -> target
    pairs, cells = success after the hand-over (95% CI) over the episodes that reached it."""
    lines = []
    for target in sorted({d["setup_config"]["target"] for d in docs}):
        group = [d for d in docs if d["setup_config"]["target"] == target]
        pairs = sorted({k for d in group for k in d if "->" in k})
        first = group[0]
        cfg = first["setup_config"]
        lines += [f"### Into {target}", "",
                  f"{first['episodes']} held-out two-artifact tracks ({first['tracks']}; source "
                  f"artifacts of {cfg['source_segments'][0]}-{cfg['source_segments'][1]} segments, "
                  f"{target} of {cfg['target_segments'][0]}-{cfg['target_segments'][1]}), hand-over "
                  f"{first['handover_m']:g} m before the {target}; success after the hand-over "
                  f"(95% CI), over the episodes that reached the setup phase.", "",
                  "| in the setup phase | " + " | ".join(pairs) + " |",
                  "|---" * (len(pairs) + 1) + "|"]
        def order(d):  # no setup, then walk, then the setup policy by training step
            name = _run_name(str(d["setup_policy"]))
            return (d["setup_policy"] != "source", not name.startswith("walk"),
                    d.get("setup_policy_step") or 0)

        for d in sorted(group, key=order):
            cells = []
            for k in pairs:
                c = d.get(k)
                cells.append("-" if c is None else
                             f"{c['success_pct']:.1f}% ({c['ci95_pct'][0]:.1f}-{c['ci95_pct'][1]:.1f}),"
                             f" n={c['n']}")
            lines.append(f"| {_who(d)} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines).rstrip()


def write_report(folder: pathlib.Path) -> pathlib.Path:
    """setup.md from every evaluation JSON in `folder`."""
    docs = [json.loads(p.read_text()) for p in sorted(folder.glob("*.json"))]
    if not docs:
        raise FileNotFoundError(f"no setup evaluation (*.json) in {folder}: run `python -m "
                                f"biped_switch.switching.setup eval --out {folder}/<name>.json`")
    out = folder / "setup.md"
    out.write_text(setup_markdown(docs) + "\n")
    return out


def main(argv=None) -> int:
    import argparse

    p = argparse.ArgumentParser(prog="python -m biped_switch.reports.setup",
                                description="setup.md from the setup evaluations in a folder")
    p.add_argument("--results", default="experiments/results/setup",
                   help="the folder of evaluation JSONs (`switching.setup eval --out`)")
    a = p.parse_args(argv)
    print(write_report(pathlib.Path(a.results)).read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
