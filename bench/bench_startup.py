"""Whole-process start-up: the CLI against what importing everything up front would cost, in one run.

Each case runs as a fresh process, best of ``REPEAT`` (the machine is shared: the
minimum is the cost itself, the rest is other work):

- ``python -c pass``: the interpreter alone (the floor);
- eager imports: numpy, scipy.signal, numba, zenoh and matplotlib, what a CLI
  importing its whole stack at start-up would pay before doing anything (the naive baseline);
- ``valvectl --help`` and ``valvectl fit --help``: the CLI imports a verb's modules only when it runs;
- ``valvectl fit`` of the bench recording (pi) end to end, with its ``fit_s`` (the fit alone:
  imports and numba's compiling and cache loading excluded, ``models/worktime.py``).

Usage: ``python bench/bench_startup.py``.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "bench_identification.csv"
REPEAT = 5
VALVECTL = [sys.executable, "-m", "controller.cli"]


def best_s(cmd: list[str]) -> float:
    """Least wall time of ``REPEAT`` runs of ``cmd``, s."""
    out = []
    for _ in range(REPEAT):
        t = time.perf_counter()
        subprocess.run(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
        out.append(time.perf_counter() - t)
    return min(out)


def main() -> None:
    print(f"whole-process start-up, best of {REPEAT}; load average {os.getloadavg()[0]:.1f}")
    floor = best_s([sys.executable, "-c", "pass"])
    eager = best_s([sys.executable, "-c", "import numpy, scipy.signal, numba, zenoh, matplotlib.pyplot"])
    print(f"  {'python -c pass (floor)':40s} {floor:6.3f} s")
    print(f"  {'eager imports (naive baseline)':40s} {eager:6.3f} s")
    for name, args in (("valvectl --help", ["--help"]), ("valvectl fit --help", ["fit", "--help"])):
        s = best_s(VALVECTL + args)
        print(f"  {name:40s} {s:6.3f} s  ({s / eager:.2f}x baseline)")
    if DATA.exists():
        with tempfile.TemporaryDirectory() as d:
            m, j = os.path.join(d, "m.json"), os.path.join(d, "f.json")
            s = best_s(VALVECTL + ["fit", str(DATA), "--model", "pi", "-o", m, "--json", j])
            fit_s = json.load(open(j))["fit_s"]
        print(f"  {'valvectl fit (pi, bench recording)':40s} {s:6.3f} s  of which fit_s {fit_s:.3f} s (the fit alone)")


if __name__ == "__main__":
    main()
