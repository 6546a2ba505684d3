"""The diagnosis on its suites, and its speed on a long recording against the implementation it replaced.

Prints, per suite:

- the detection rate per effect word and magnitude (the injected word among the findings);
- the confusion matrix: injected word (rows) x named words (columns);
- false findings: effect-free recordings with any finding;
- the held-out improvement: for every finding, holdout RMSE after / before.

Suites: ``matrix`` (:func:`diagnose_suite.matrix`: every word at 1, 5 and 30 times the noise on
the paper sweep, steps, ramps, random holds, breaths and a closed-loop run, plus each
excitation effect free), ``concealed`` (:func:`diagnose_suite.cases`, effects the size of the
noise on four excitations, and pairs) and ``foreign`` (:mod:`diagnose_foreign`, made without
plant_sim).

Then times ``diagnose_response`` on a 150 000-row recording at 200 Hz, each implementation in a
fresh process: this tree's, and the one this work started from (commit :data:`START_COMMIT`,
checked out as a git worktree in the temporary folder), and prints the ratio and peak memory.

    .venv/bin/python bench/bench_diagnose.py [--suite matrix,concealed,foreign] [--quick] [--workers N]
                                             [--no-timing]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections import Counter, defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

# one BLAS thread per process, as the CLI runs (controller/cli.py): threads spin against each
# other on a shared machine
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

import diagnose_foreign as F  # noqa: E402
import diagnose_suite as S  # noqa: E402
from models.diagnose.words import WORDS  # noqa: E402

#: The diagnosis this work replaced (issue 14 started here): the timing baseline.
START_COMMIT = "5630bab"


def run_case(case):
    from models.diagnose import diagnose_response
    from models.model import load_model

    foreign = isinstance(case, F.Case)
    rec = (F if foreign else S).record(case)
    model = None
    if case.with_model:
        model = F.model_file() if foreign else load_model(S.MODEL_JSON)
    t0 = time.perf_counter()
    d = diagnose_response(rec, model)
    return case, d.baseline.r, [(f.effect, f.holdout_rmse_before, f.holdout_rmse_after, f.alternative_to)
                                for f in d.findings], time.perf_counter() - t0, set(d.model["not_identifiable"])


def report(title: str, results: list, wall: float, workers: int) -> None:
    """Print one suite's detection rates (per word and magnitude), confusion, false findings and
    held-out improvement."""
    detected, total, as_alt = Counter(), Counter(), Counter()
    by_size = defaultdict(Counter)
    confusion = defaultdict(Counter)
    free_total, free_fp = 0, []
    ratios, worse = [], []
    said = Counter()
    for case, r, found, _, unseen in results:
        named = [f[0] for f in found]
        for f in found:
            ratios.append(f[2] / f[1])
            if f[2] >= f[1]:
                worse.append((case.label(), f))
        if not case.words:
            free_total += 1
            if named:
                free_fp.append((case.label(), named))
            for w in named or ["-"]:
                confusion["(none)"][w] += 1
            continue
        alternatives = {f[0] for f in found if f[3] is not None}
        size = getattr(case, "size", 1.0)
        for w in case.words:
            total[w] += 1
            detected[w] += w in named
            as_alt[w] += w in alternatives
            by_size[(w, size)]["n"] += 1
            by_size[(w, size)]["hit"] += w in named
            # not named, and the diagnosis said why: the excitation cannot show it (counted as a miss
            # in the detection rate, and apart)
            said[size] += w not in named and w in unseen
            for v in named or ["-"]:
                confusion[w][v] += 1
    print(f"\n=== {title}: {len(results)} recordings in {wall:.0f} s ({workers} workers)")
    sizes = sorted({s for _, s in by_size})
    print("\ndetection per effect word (injected word among the findings; 'alt': only as the alternative of a "
          "lag or delay the recording cannot tell apart), by magnitude (x noise):")
    print(f"  {'word':24s}" + "".join(f"{f'{s:g}x':>12s}" for s in sizes) + f"{'all':>14s}")
    for w in WORDS:
        if total[w]:
            cells = "".join(f"{by_size[(w, s)]['hit']:>5d}/{by_size[(w, s)]['n']:<6d}" if by_size[(w, s)]["n"]
                            else f"{'-':>12s}" for s in sizes)
            print(f"  {w:24s}{cells}{100 * detected[w] / total[w]:8.1f} % (alt {as_alt[w]})")
    all_d, all_t = sum(detected.values()), sum(total.values())
    if all_t:
        per_size = "".join(
            f"{100 * sum(by_size[(w, s)]['hit'] for w in WORDS) / max(1, sum(by_size[(w, s)]['n'] for w in WORDS)):>11.1f}%"
            for s in sizes)
        print(f"  {'all':24s}{per_size}{100 * all_d / all_t:8.1f} % (alt {sum(as_alt.values())})")
        print("  of the misses, reported as not identifiable on the excitation (the diagnosis says it cannot see "
              "the word there, rather than guessing): " + ", ".join(f"{said[s]} at {s:g}x" for s in sizes))
    print(f"\nfalse findings: {len(free_fp)}/{free_total} effect-free recordings with a finding")
    for label, named in free_fp[:10]:
        print(f"  {named} in {label}")
    cols = list(WORDS) + ["-"]
    short = {w: w[:6] for w in WORDS} | {"-": "none"}
    print("\nconfusion (rows injected, columns named; a recording counts once per named word):")
    print(" " * 24 + " ".join(f"{short[c]:>6s}" for c in cols))
    for w in ["(none)"] + list(WORDS):
        if confusion[w]:
            print(f"  {w:22s}" + " ".join(f"{confusion[w][c]:6d}" for c in cols))
    if ratios:
        q = np.percentile(ratios, [50, 90, 100])
        print(f"\nheld-out RMSE after/before per finding: median {q[0]:.3f}, 90th percentile {q[1]:.3f}, max {q[2]:.3f}; "
              f"not lower in {len(worse)}/{len(ratios)} findings")
        for label, f in worse[:10]:
            print(f"  {f[0]} {f[1]:.4f} -> {f[2]:.4f} in {label}")


TIMING = r"""
import json, resource, sys, time
import numpy as np
from models.diagnose import diagnose_response
from models.recording import read_recording
rec = read_recording(sys.argv[1])
diagnose_response(rec.slice(0, 6000))  # compiled kernels loaded before the clock starts
t0, c0 = time.perf_counter(), time.process_time()
d = diagnose_response(rec)
print(json.dumps({"s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0,
                  "findings": [f.effect for f in d.findings],
                  "maxrss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def start_tree(commit: str = START_COMMIT) -> Path:
    """A git worktree of ``commit`` in the temporary folder (made once)."""
    path = Path(tempfile.gettempdir()) / f"valvectl-diagnose-{commit}"
    if not (path / "models" / "diagnose").exists():
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(path), commit], check=True,
                       capture_output=True)
    return path


def timed(tree: Path, csv: Path) -> dict:
    """Run the timing snippet with ``tree``'s diagnosis in a fresh process."""
    env = {**os.environ, "PYTHONPATH": str(tree), "OPENBLAS_NUM_THREADS": "1"}
    out = subprocess.run([sys.executable, "-c", TIMING, str(csv)], cwd=tree, env=env, check=True,
                         capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def long_recording_timing() -> None:
    from models.recording import Recording, write_recording

    rate, n = 200.0, 150_000
    duty = S.excitation("random_holds", 5, rate_hz=rate, duration_s=n / rate)
    params = S.load_plant(S.PLANT_TOML, effects={"valve_dynamics": 0.03}, noise_lpm=0.5)
    cols = S.Plant(params, rate, seed=5).simulate(duty)
    rec = Recording("<150k rows>", {k: np.asarray(cols[k], dtype=float) for k in ("t_s", "duty_pct", "flow_lpm")})
    with tempfile.TemporaryDirectory() as tmp:
        csv = Path(tmp) / "long.csv"
        write_recording(csv, rec.columns)
        old = timed(start_tree(), csv)
        new = timed(ROOT, csv)
    print(f"\n150 000 rows at 200 Hz (valve_dynamics 0.03 s injected), each in a fresh process, same run:")
    for name, r in ((f"start ({START_COMMIT})", old), ("this tree", new)):
        print(f"  {name:16s} {r['s']:6.1f} s wall, {r['cpu_s']:6.1f} s CPU, peak {r['maxrss_mb']:.0f} MB, "
              f"findings {r['findings']}")
    print(f"  ratio this/start: {new['cpu_s'] / old['cpu_s']:.2f} x the CPU time, {new['s'] / old['s']:.2f} x the wall "
          f"time (on a machine shared with other work), {new['maxrss_mb'] / old['maxrss_mb']:.2f} x the memory "
          f"(target: within 15 s on 2 cores); {os.cpu_count()} CPUs")


def suites(names: list, quick: bool) -> list:
    out = []
    if "matrix" in names:
        left = []
        cases = (S.matrix(excitations=("paper", "steps", "breaths"), sizes=(5.0, 30.0), left_out=left) if quick
                 else S.matrix(left_out=left))
        unreached = ", ".join(f"{w} {s:g}x on {e} (reaches {r:.2g}x)" for w, e, _, s, r in left)
        out.append((f"magnitude x excitation matrix ({len(left)} word/excitation/magnitude cases left out: the "
                    f"excitation cannot show the effect that large within four times its plausible size: "
                    f"{unreached})", cases))
    if "concealed" in names:
        out.append(("concealed suite (plant_sim)",
                    S.cases(seeds=(1,), noises=(0.5,), pairs=True) if quick else S.cases()))
    if "foreign" in names:
        foreign, left_out = F.cases(seeds=(1,), noises=(0.3,)) if quick else F.cases()
        out.append((f"foreign suite ({len(left_out)} word/excitation cases left out: the excitation cannot show "
                    f"the effect at the noise level)", foreign))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--suite", default="matrix,concealed,foreign", help="comma-separated: matrix, concealed, foreign")
    ap.add_argument("--quick", action="store_true", help="a small part of each suite")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--no-timing", action="store_true")
    args = ap.parse_args()
    if not args.no_timing:
        long_recording_timing()
    for title, cases in suites([s.strip() for s in args.suite.split(",") if s.strip()], args.quick):
        t0 = time.perf_counter()
        with ProcessPoolExecutor(args.workers) as ex:
            results = list(ex.map(run_case, cases, chunksize=1))
        report(title, results, time.perf_counter() - t0, args.workers)
    return 0


if __name__ == "__main__":
    sys.exit(main())
