"""Sweep speed and rows: this checkout against a baseline commit's implementation, in one run.

Prints the figures of issue 16's "Done when" for the default sweep
(``config/sweep.toml``: 1019 candidates x 3 plant variants x 5 s at 1 kHz):

- **warm**: the sweep's own ``seconds`` (what ``valvectl sweep`` reports: build, simulate,
  rank, margins; imports and kernel loading excluded by a small sweep before it in the
  same process), best and median over ``--rounds`` fresh processes, alternating this
  checkout and the baseline (``--baseline``, default 7a8da92: main when the sweep's
  speed work of this session began), so both see the same machine; the ratio of the two;
  also their CPU seconds (process and pool workers), which a busy machine moves less;
- **rows**: the largest relative difference of every figure against the issue's original
  sweep (:mod:`bench.sweep_rows`: commit 9861ad8, stored rows), for this checkout and for
  the baseline;
- **first run** (``--first-run``): wall seconds of ``valvectl sweep`` as the first process
  after install, in a temporary copy of this checkout whose numba caches start empty:
  the install's ahead-of-time compile (``make setup``'s ``python -m controller.precompile``)
  timed apart, then the sweep process from start to exit; with ``--cold`` also the
  first run of a copy nobody precompiled (the run compiles its kernels itself).

The baseline is unpacked once (``git archive``) into ``$TMPDIR/valvectl-bench-COMMIT`` and its
kernels compiled there on first use; later bench runs reuse it. Run at normal priority on a
quiet machine (the load average is printed): the machine's other work is in every figure.

Usage: ``python bench/bench_sweep.py [--rounds N] [--baseline COMMIT] [--first-run] [--cold]``.
"""
from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import sweep_rows  # noqa: E402

ROOT = sweep_rows.ROOT
SWEEP = ROOT / "config" / "sweep.toml"
WARM_LIMIT_S, FIRST_LIMIT_S, ROWS_LIMIT = 3.0, 6.0, 1e-9


def baseline_tree(commit: str) -> Path:
    """The baseline's files, unpacked and precompiled once (kept for later bench runs)."""
    tree = Path(tempfile.gettempdir()) / f"valvectl-bench-{commit}"
    if not (tree / ".precompiled").exists():
        sweep_rows.unpack(commit, tree)
        print(f"  (baseline {commit}: compiling its kernels into {tree}, once)", flush=True)
        precompile(tree)
        (tree / ".precompiled").touch()
    return tree


def precompile(tree: Path) -> float:
    """``make setup``'s ahead-of-time step in ``tree``, under SCHED_IDLE (not a figure of the sweep: it
    yields to the timings of others on a shared machine); wall seconds."""
    idle = ["chrt", "-i", "0", "nice", "-n", "19"] if shutil.which("chrt") else []
    t = time.perf_counter()
    subprocess.run([*idle, sys.executable, "-m", "controller.precompile"], cwd=tree, check=True,
                   stdout=subprocess.DEVNULL, env={**os.environ, "PYTHONPATH": str(tree)})
    return time.perf_counter() - t


def copy_checkout(dest: Path) -> Path:
    """This checkout's files (tracked and untracked, not ignored: no caches, no .venv) in ``dest``."""
    files = subprocess.run(["git", "-C", str(ROOT), "ls-files", "-co", "--exclude-standard", "-z"], check=True,
                           capture_output=True).stdout.decode().split("\0")
    for f in filter(None, files):
        src = ROOT / f
        if src.is_file():
            (dest / f).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / f)
    return dest


def first_run_s(tree: Path, out: Path) -> float:
    """Wall seconds of ``valvectl sweep`` in ``tree`` as a fresh process, start to exit."""
    t = time.perf_counter()
    subprocess.run([sys.executable, "-m", "controller.cli", "sweep", "-o", str(out)], cwd=tree, check=True,
                   stdout=subprocess.DEVNULL, env={**os.environ, "PYTHONPATH": str(tree)})
    return time.perf_counter() - t


def stats(xs: list[float]) -> tuple[float, float]:
    return min(xs), statistics.median(xs)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3, help="fresh processes per implementation, alternating")
    ap.add_argument("--baseline", default="7a8da92", help="commit whose implementation is the baseline")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--first-run", action="store_true", help="also the first run after install (a temporary copy)")
    ap.add_argument("--cold", action="store_true", help="with --first-run: also a first run nobody precompiled")
    a = ap.parse_args()

    print(f"sweep {SWEEP.relative_to(ROOT)}, {a.workers} workers; load average {os.getloadavg()[0]:.1f}")
    base = baseline_tree(a.baseline)
    original = sweep_rows.load_stored()
    warm = {"this checkout": [], f"baseline {a.baseline}": []}
    cpu = {k: [] for k in warm}
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(a.rounds):
            order = [("this checkout", ROOT), (f"baseline {a.baseline}", base)]
            for name, tree in order if i % 2 == 0 else order[::-1]:
                # each implementation on its own config/ (a newer run.toml may hold keys an older schema refuses)
                r = sweep_rows.run_in_tree(tree, tree / SWEEP.relative_to(ROOT), Path(tmp) / "rows.json", a.workers)
                warm[name].append(r["seconds"])
                cpu[name].append(r["cpu_s"])
                rows.setdefault(name, r)
        print(f"warm sweep seconds over {a.rounds} rounds (load average now {os.getloadavg()[0]:.1f}):")
        for name, xs in warm.items():
            best, med = stats(xs)
            print(f"  {name:22s} best {best:5.2f} s  median {med:5.2f} s  ({', '.join(f'{x:.2f}' for x in xs)})")
        (b_new, m_new), (b_old, m_old) = (stats(xs) for xs in warm.values())
        print(f"  ratio this/baseline: best {b_new / b_old:.2f}, median {m_new / m_old:.2f}; "
              f"{'within' if b_new <= WARM_LIMIT_S else 'NOT within'} {WARM_LIMIT_S:g} s (best)")
        print("  CPU seconds of the sweep (process and pool workers; moves less than wall time on a busy machine):")
        for name, xs in cpu.items():
            best, med = stats(xs)
            print(f"  {name:22s} best {best:5.2f} s  median {med:5.2f} s")
        (c_new, _), (c_old, _) = (stats(xs) for xs in cpu.values())
        print(f"  ratio this/baseline (CPU, best): {c_new / c_old:.2f}")
        print(f"rows against the original sweep (commit {original['commit']}):")
        for name, r in rows.items():
            n, n_diff, worst = sweep_rows.difference(original, r)
            print(f"  {name:22s} {n_diff} of {n} figures differ, largest relative difference {worst:.2e} "
                  f"({'within' if worst <= ROWS_LIMIT else 'NOT within'} {ROWS_LIMIT:g})")

        if a.first_run:
            cases = [("after install", True)] + ([("nobody precompiled", False)] if a.cold else [])
            for name, install in cases:
                tree = copy_checkout(Path(tmp) / name.replace(" ", "_"))
                extra = ""
                if install:
                    extra = f" (the install's precompile before it: {precompile(tree):.1f} s)"
                s = first_run_s(tree, Path(tmp) / "first.csv")
                print(f"first run {name}: {s:.2f} s wall{extra}; "
                      f"{'within' if s <= FIRST_LIMIT_S else 'NOT within'} {FIRST_LIMIT_S:g} s")


if __name__ == "__main__":
    main()
