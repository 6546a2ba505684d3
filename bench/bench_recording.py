"""Reading a 1.8 M-row recording: the vectorized reader against the per-cell reader it replaced, same run.

The baseline is ``models/recording.py`` as it was at commit ``BASELINE`` (the
Python loop over lines and cells), loaded from git history at run time, so
both read the same file on the same machine in the same run. Both must return
the same columns. Prints seconds per read (best of ``--repeat``) and the ratio.

    python bench/bench_recording.py [--rows 1800000] [--repeat 3]
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
import types

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from models.recording import read_recording, write_recording  # noqa: E402

#: The last commit with the per-cell reader.
BASELINE = "5630bab"


def baseline_reader():
    """``read_recording`` of :data:`BASELINE`, from git history."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    src = subprocess.run(["git", "show", f"{BASELINE}:models/recording.py"], cwd=root, check=True,
                         capture_output=True, text=True).stdout
    mod = types.ModuleType("baseline_recording")
    sys.modules[mod.__name__] = mod  # dataclasses look their module up
    exec(compile(src, f"{BASELINE}:models/recording.py", "exec"), mod.__dict__)
    return mod.read_recording


def make_recording(path: str, rows: int, seed: int = 0) -> None:
    """A simulate-like recording at 1 kHz: t_s, duty_pct, flow_lpm, supply_bar, coil_temp_c."""
    rng = np.random.default_rng(seed)
    t = np.arange(rows) / 1000.0
    duty = 50.0 + 30.0 * np.sin(2 * np.pi * 0.2 * t)
    write_recording(path, {"t_s": t, "duty_pct": duty, "flow_lpm": 2.0 * duty + rng.normal(0, 0.5, rows),
                           "supply_bar": 3.0 + rng.normal(0, 0.01, rows), "coil_temp_c": 25.0 + 0.001 * t})


def timed(fn) -> tuple[float, object]:
    start = time.perf_counter()
    out = fn()
    return time.perf_counter() - start, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=1_800_000)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    old = baseline_reader()
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "big.csv")
        make_recording(path, a.rows)
        size_mb = os.path.getsize(path) / 1e6
        # interleaved, best of each: a machine whose load changes during the run affects both alike
        t_new = t_old = float("inf")
        for _ in range(a.repeat):
            t, new = timed(lambda: read_recording(path))
            t_new = min(t_new, t)
            t, ref = timed(lambda: old(path))
            t_old = min(t_old, t)
    for k, v in ref.columns.items():
        np.testing.assert_array_equal(new.columns[k], v, err_msg=k)
    print(f"{a.rows} rows ({size_mb:.0f} MB), best of {a.repeat}, interleaved:")
    print(f"  baseline reader ({BASELINE}): {t_old:7.2f} s")
    print(f"  vectorized reader:        {t_new:7.2f} s")
    print(f"  speed-up: {t_old / t_new:.1f}x (target >= 3x)")


if __name__ == "__main__":
    main()
