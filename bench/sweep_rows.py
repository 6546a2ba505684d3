"""A sweep's rows from any commit's implementation, and how far two sets of rows differ.

The rows of record are the issue's original sweep: ``config/sweep.toml`` as
the implementation of commit :data:`ORIGINAL` computed it (numpy laws
stepped from Python once per period, ``controller/tuning.py``'s closed loop,
before the compiled laws of issue 16), stored in ``bench/data/`` so a bench
run needs no compile of the old code. Run this file to write them again
(the old commit is unpacked with ``git archive`` into a temporary folder and
run with this checkout's Python environment, on its own ``config/``), with the
law changes made since applied to it in its own numpy terms
(:data:`LAW_PATCHES`, the same the compiled laws' reference test applies: the
Kalman bias held while the model has the valve closed), so that the rows
measure the speed work alone.

Usage: ``python bench/sweep_rows.py [COMMIT]``.
"""
from __future__ import annotations

import gzip
import json
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ORIGINAL = "9861ad8"
STORED = ROOT / "bench" / "data" / f"sweep_rows_{ORIGINAL}.json.gz"
#: Law changes since :data:`ORIGINAL`, as patches of its numpy laws.
LAW_PATCHES = sorted((ROOT / "tests" / "data" / "sweep_reference").glob("*.patch"))

#: Run in a tree (cwd and PYTHONPATH): ``SWEEP.toml OUT.json WORKERS WARM``. A warm run first (a
#: two-candidate sweep: kernels loaded, python-control imported), then the timed sweep, its rows
#: at full precision, its ``seconds`` (the sweep's own figure, as ``valvectl sweep`` reports it) and the
#: CPU seconds of the process and its pool workers over the sweep.
SCRIPT = """
import dataclasses, json, math, resource, sys
from controller.sweep import runner, spec
s = spec.load_sweep(sys.argv[1])
workers, warm = int(sys.argv[3]), sys.argv[4] == "1"
if warm:
    runner.run_sweep(dataclasses.replace(s, candidates=s.candidates.take([0, len(s.candidates) - 1]), margins_top=0),
                     workers=1)
def cpu_s():
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime
c0 = cpu_s()
r = runner.run_sweep(s, workers=workers)
cpu = cpu_s() - c0
def cell(v):
    return None if v is None or (isinstance(v, float) and math.isnan(v)) else v
table = {c: [cell(v if isinstance(v, str) or v is None else float(v)) for v in r.table[c]] for c in r.columns}
json.dump({"columns": r.columns, "table": table, "seconds": r.seconds, "cpu_s": cpu}, open(sys.argv[2], "w"))
"""


def run_in_tree(tree: str | Path, sweep: str | Path, out: str | Path, workers: int = 2, warm: bool = True,
                python: str = sys.executable) -> dict:
    """Run the sweep file ``sweep`` with the implementation in ``tree``; its rows and seconds."""
    subprocess.run([python, "-c", SCRIPT, str(sweep), str(out), str(workers), "1" if warm else "0"], cwd=tree,
                   check=True, env={**os.environ, "PYTHONPATH": str(tree)})
    with open(out) as fh:
        return json.load(fh)


def unpack(commit: str, dest: str | Path) -> Path:
    """The files of ``commit`` (``git archive``) in ``dest``, created if missing."""
    dest = Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", commit], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    return dest


def load_stored() -> dict:
    with gzip.open(STORED, "rt") as fh:
        return json.load(fh)


def difference(a: dict, b: dict) -> tuple[int, int, float]:
    """``(figures, figures that differ, largest relative difference)`` between two sets of rows.

    Parameter columns must agree exactly; a missing figure (NaN, or a margin not computed) must be
    missing in both, and an infinite one infinite in both (else the difference counts as inf).
    """
    if a["columns"] != b["columns"]:
        raise ValueError(f"columns differ: {a['columns']} against {b['columns']}")
    n = n_diff = 0
    worst = 0.0
    for c in a["columns"]:
        for x, y in zip(a["table"][c], b["table"][c], strict=True):
            if isinstance(x, str) or isinstance(y, str) or x is None or y is None:
                if x != y:
                    n_diff, worst = n_diff + 1, math.inf
                continue
            n += 1
            if x == y:
                continue
            n_diff += 1
            worst = max(worst, abs(x - y) / max(abs(x), abs(y)) if math.isfinite(x) and math.isfinite(y) else math.inf)
    return n, n_diff, worst


def main() -> None:
    commit = sys.argv[1] if len(sys.argv) > 1 else ORIGINAL
    with tempfile.TemporaryDirectory() as tmp:
        tree = unpack(commit, Path(tmp) / "tree")
        for patch in LAW_PATCHES:
            subprocess.run(["git", "apply", str(patch)], cwd=tree, check=True)
        rows = run_in_tree(tree, tree / "config" / "sweep.toml", Path(tmp) / "rows.json", warm=False)
    rows = {"commit": commit, "law_patches": [p.name for p in LAW_PATCHES], **rows}
    STORED.parent.mkdir(exist_ok=True)
    with gzip.open(STORED, "wt") as fh:
        json.dump(rows, fh)
    print(f"{STORED}: {len(rows['table']['controller'])} rows of config/sweep.toml from {commit} with {[p.name for p in LAW_PATCHES]}")


if __name__ == "__main__":
    main()
