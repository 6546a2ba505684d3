"""The diagnosis on its concealed-effect suite (plant_sim), and its speed on a long recording.

Prints, over the suite of :mod:`diagnose_suite` (every effect word, effect
free, and two-effect recordings; several seeds, noise levels, excitations):

- the share of cases whose baseline fit looks fine (r >= 0.998);
- the detection rate per effect word (the injected word among the findings);
- the confusion matrix: injected word (rows) x named words (columns);
- the false-positive rate on effect-free recordings;
- the held-out improvement: for every finding, holdout RMSE after / before;

then times ``diagnose_response`` on a 150 000-row recording at 200 Hz, as a
ratio to the paper's PI fit on the same recording (``fit_recording``).

    .venv/bin/python bench/bench_diagnose.py [--quick] [--workers N]
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from collections import Counter, defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

import diagnose_suite as S  # noqa: E402


def run_case(case):
    from models.diagnose import diagnose_response
    from models.model import load_model

    rec = S.record(case)
    model = load_model(S.MODEL_JSON) if case.with_model else None
    t0 = time.perf_counter()
    d = diagnose_response(rec, model)
    return case, d.baseline.r, [(f.effect, f.holdout_rmse_before, f.holdout_rmse_after) for f in d.findings], \
        time.perf_counter() - t0


def long_recording_timing() -> None:
    from models.diagnose import diagnose_response
    from models.fitting import fit_recording

    rate, n = 200.0, 150_000
    duty = S.excitation("random_holds", 5, rate_hz=rate, duration_s=n / rate)
    params = S.load_plant(S.PLANT_TOML, effects={"valve_dynamics": 0.03}, noise_lpm=0.5)
    cols = S.Plant(params, rate, seed=5).simulate(duty)
    rec = S.Recording("<150k rows>", {k: np.asarray(cols[k], dtype=float) for k in ("t_s", "duty_pct", "flow_lpm")})
    t0 = time.perf_counter()
    fit_recording("pi", rec)
    t_fit = time.perf_counter() - t0
    t0 = time.perf_counter()
    d = diagnose_response(rec)
    t_diag = time.perf_counter() - t0
    print(f"\n150 000 rows at 200 Hz: diagnose {t_diag:.1f} s (limit 60 s), {t_diag / t_fit:.1f} x the paper's PI fit "
          f"alone ({t_fit:.2f} s); findings {[f.effect for f in d.findings]} (injected valve_dynamics = 0.03 s); "
          f"{os.cpu_count()} CPUs, shared with other work")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one seed, one noise level (about a tenth of the suite)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--no-timing", action="store_true")
    args = ap.parse_args()
    if args.quick:
        cases = S.cases(seeds=(1,), noises=(0.5,), pairs=True)
    else:
        cases = S.cases()
    t0 = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as ex:
        results = list(ex.map(run_case, cases, chunksize=2))
    wall = time.perf_counter() - t0

    detected, total = Counter(), Counter()
    confusion = defaultdict(Counter)
    free_total = free_fp = 0
    ratios, worse = [], []
    fine = 0
    for case, r, found, _ in results:
        fine += r >= 0.998
        named = [f[0] for f in found]
        for f in found:
            ratios.append(f[2] / f[1])
            if f[2] >= f[1]:
                worse.append((case.label(), f))
        if not case.words:
            free_total += 1
            free_fp += bool(named)
            for w in named:
                confusion["(none)"][w] += 1
            if not named:
                confusion["(none)"]["-"] += 1
            continue
        for w in case.words:
            total[w] += 1
            detected[w] += w in named
            for v in named or ["-"]:
                confusion[w][v] += 1
    print(f"suite: {len(results)} recordings in {wall:.0f} s ({args.workers} workers); baseline r >= 0.998 in "
          f"{fine}/{len(results)}")
    print("\ndetection rate per effect word (injected word among the findings):")
    for w in S.WORDS:
        if total[w]:
            print(f"  {w:24s} {detected[w]:3d}/{total[w]:3d} = {100 * detected[w] / total[w]:5.1f} %")
    all_d, all_t = sum(detected.values()), sum(total.values())
    print(f"  {'all':24s} {all_d:3d}/{all_t:3d} = {100 * all_d / all_t:5.1f} %")
    print(f"\nfalse positives on effect-free recordings: {free_fp}/{free_total} recordings with a finding")
    cols = list(S.WORDS) + ["-"]
    short = {w: w[:6] for w in S.WORDS} | {"-": "none"}
    print("\nconfusion (rows injected, columns named; a recording counts once per named word):")
    print(" " * 24 + " ".join(f"{short[c]:>6s}" for c in cols))
    for w in ["(none)"] + list(S.WORDS):
        if confusion[w]:
            print(f"  {w:22s}" + " ".join(f"{confusion[w][c]:6d}" for c in cols))
    if ratios:
        q = np.percentile(ratios, [50, 90, 100])
        print(f"\nheld-out RMSE after/before per finding: median {q[0]:.3f}, 90th percentile {q[1]:.3f}, max {q[2]:.3f}; "
              f"not lower in {len(worse)}/{len(ratios)} findings")
        for label, f in worse[:10]:
            print(f"  {f[0]} {f[1]:.4f} -> {f[2]:.4f} in {label}")
    if not args.no_timing:
        long_recording_timing()
    return 0


if __name__ == "__main__":
    sys.exit(main())
