"""The diagnosis on its concealed-effect suites, and its speed on a long recording.

Prints, over the suite of :mod:`diagnose_suite` (plant_sim: every effect
word, effect free, and two-effect recordings; several seeds, noise levels,
excitations), then over the foreign suite of :mod:`diagnose_foreign` (a valve
and effects coded without plant_sim):

- the share of cases whose baseline fit looks fine (r >= 0.998);
- the detection rate per effect word (the injected word among the findings);
- the confusion matrix: injected word (rows) x named words (columns);
- the false-positive rate on effect-free recordings;
- the held-out improvement: for every finding, holdout RMSE after / before;

then times ``diagnose_response`` on a 150 000-row recording at 200 Hz, as a
ratio to the paper's PI fit on the same recording (``fit_recording``).

    .venv/bin/python bench/bench_diagnose.py [--quick] [--workers N] [--no-foreign] [--no-timing]
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

import diagnose_foreign as F  # noqa: E402
import diagnose_suite as S  # noqa: E402


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
                                for f in d.findings], time.perf_counter() - t0


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


def report(title: str, results: list, wall: float, workers: int) -> None:
    """Print one suite's detection rates, confusion, false positives and held-out improvement."""
    detected, total, as_alt = Counter(), Counter(), Counter()
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
        alternatives = {f[0] for f in found if f[3] is not None}
        for w in case.words:
            total[w] += 1
            detected[w] += w in named
            as_alt[w] += w in alternatives
            for v in named or ["-"]:
                confusion[w][v] += 1
    print(f"\n=== {title}: {len(results)} recordings in {wall:.0f} s ({workers} workers); baseline r >= 0.998 in "
          f"{fine}/{len(results)}")
    print("\ndetection rate per effect word (injected word among the findings; of those, how many only as the "
          "alternative to a lag or delay the recording cannot tell apart):")
    for w in S.WORDS:
        if total[w]:
            print(f"  {w:24s} {detected[w]:3d}/{total[w]:3d} = {100 * detected[w] / total[w]:5.1f} %"
                  f"   (as alternative: {as_alt[w]})")
    all_d, all_t = sum(detected.values()), sum(total.values())
    print(f"  {'all':24s} {all_d:3d}/{all_t:3d} = {100 * all_d / all_t:5.1f} %   (as alternative: "
          f"{sum(as_alt.values())}; named outright {100 * (all_d - sum(as_alt.values())) / all_t:.1f} %)")
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


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one seed, one noise level (about a tenth of the suites)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--no-foreign", action="store_true", help="skip the suite made without plant_sim")
    ap.add_argument("--no-timing", action="store_true")
    args = ap.parse_args()
    suites = [("plant_sim suite", S.cases(seeds=(1,), noises=(0.5,), pairs=True) if args.quick else S.cases())]
    if not args.no_foreign:
        foreign, left_out = F.cases(seeds=(1,), noises=(0.3,)) if args.quick else F.cases()
        suites.append((f"foreign suite ({len(left_out)} word/excitation cases left out: the excitation cannot show "
                       f"the effect at the noise level)", foreign))
    for title, cases in suites:
        t0 = time.perf_counter()
        with ProcessPoolExecutor(args.workers) as ex:
            results = list(ex.map(run_case, cases, chunksize=2))
        report(title, results, time.perf_counter() - t0, args.workers)
    if not args.no_timing:
        long_recording_timing()
    return 0


if __name__ == "__main__":
    sys.exit(main())
