"""Write reference.json: the rows of sweep.toml as the numpy laws computed them before they were compiled (commit a3541a9).

Checks the commit out into a temporary git worktree, applies the law changes
made since, written in the numpy laws' own terms (``*.patch`` here: the Kalman
bias held while the model has the valve closed, ef50fd0), runs the sweep there
(with this checkout's Python environment) and stores every column at full
precision. Usage: ``python tests/data/sweep_reference/make_reference.py [COMMIT]``.
"""
from __future__ import annotations

import glob
import os
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(HERE)))

RUN = """
import json, math, sys
from controller.sweep import runner, spec
r = runner.run_sweep(spec.load_sweep(sys.argv[1]), workers=1)
def cell(v):
    return None if v is None or (isinstance(v, float) and math.isnan(v)) else v
table = {c: [cell(v if isinstance(v, str) or v is None else float(v)) for v in r.table[c]] for c in r.columns}
json.dump({"commit": sys.argv[3], "columns": r.columns, "table": table}, open(sys.argv[2], "w"))
"""


def main() -> None:
    commit = sys.argv[1] if len(sys.argv) > 1 else "a3541a9"
    with tempfile.TemporaryDirectory() as tmp:
        tree = os.path.join(tmp, "tree")
        subprocess.run(["git", "-C", ROOT, "worktree", "add", "--detach", tree, commit], check=True,
                       stdout=subprocess.DEVNULL)
        try:
            for patch in sorted(glob.glob(os.path.join(HERE, "*.patch"))):
                subprocess.run(["git", "-C", tree, "apply", patch], check=True)
            subprocess.run([sys.executable, "-c", RUN, os.path.join(HERE, "sweep.toml"),
                            os.path.join(HERE, "reference.json"), commit], cwd=tree, check=True,
                           env={**os.environ, "PYTHONPATH": tree})
        finally:
            subprocess.run(["git", "-C", ROOT, "worktree", "remove", "--force", tree], check=True)
    print(f"{HERE}/reference.json from {commit}")


if __name__ == "__main__":
    main()
