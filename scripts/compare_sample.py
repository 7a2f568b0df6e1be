"""Compares two `scripts/compare_sample.sh` outputs: every Table I and II row's numbers and every
per-trial array must be equal, bit for bit (paths and wall times may differ)."""
import json
import sys

import numpy as np

# where a row's inputs came from, and how long it took: not what it measured
IGNORE = {"wall_s", "elapsed_s", "time_s", "checkpoint", "eval_wall_s", "policies", "switch_parts",
          "detector"}


def main(a: str, b: str) -> int:
    bad = 0
    for t in ("t1", "t2"):
        ra = json.load(open(f"{a}/{t}/table{t[1]}.json"))["rows"]
        rb = json.load(open(f"{b}/{t}/table{t[1]}.json"))["rows"]
        assert len(ra) == len(rb), (len(ra), len(rb))
        for x, y in zip(ra, rb):
            diff = sorted(k for k in set(x) | set(y) if k not in IGNORE and x.get(k) != y.get(k))
            name = x.get("method") or f"{x.get('policy')}/{x.get('init')}"
            print(f"{t} {name}: {'identical' if not diff else 'DIFFERS in ' + ', '.join(diff)}")
            bad += bool(diff)
    d1, d2 = np.load(f"{a}/t2/table2_trials.npz"), np.load(f"{b}/t2/table2_trials.npz")
    common = [k for k in d1.files if k in d2.files]
    missing = [k for k in d1.files if k not in d2.files]
    arr = [k for k in common if not np.array_equal(d1[k], d2[k], equal_nan=True)] + missing
    new = sorted({k.split("/")[1] for k in d2.files if k not in d1.files})
    print(f"per-trial arrays ({len(common)}):", "identical" if not arr else f"DIFFER: {arr}",
          f"(new fields: {', '.join(new)})" if new else "")
    return 1 if bad or arr else 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:3]))
