"""Executes every notebook in experiments/notebooks/ on the committed results and saves it with
its outputs, so the repository shows the tables and figures (`make notebooks`). The notebook tests
execute them again on their own copies."""
from __future__ import annotations

import pathlib
import sys
import time

import nbformat
from nbclient import NotebookClient

NB_DIR = pathlib.Path(__file__).resolve().parents[1] / "experiments" / "notebooks"


def main(names: list[str]) -> int:
    paths = [NB_DIR / f"{n}.ipynb" for n in names] if names else sorted(NB_DIR.glob("*.ipynb"))
    for path in paths:
        t0 = time.time()
        nb = nbformat.read(path, as_version=4)
        NotebookClient(nb, timeout=1200, kernel_name="python3",
                       resources={"metadata": {"path": str(NB_DIR)}}).execute()
        for cell in nb.cells:  # keep diffs small: no execution timestamps
            cell.get("metadata", {}).pop("execution", None)
        nbformat.write(nb, path)
        print(f"{path.name}: executed in {time.time() - t0:.0f} s, "
              f"{path.stat().st_size / 1e3:.0f} kB with outputs", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
