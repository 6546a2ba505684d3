"""Play-operator and PI fit speed against a plain per-sample numpy loop, in one run.

Prints samples per second for n = 50 operators at 1e5 and 1e6 samples
(full operator response and weighted output), and the PI fit time on
../shared/data/bench_identification.csv against the same fit built on the
plain loop.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from models import play  # noqa: E402
from tests import oracles  # noqa: E402
from models.fitting import evaluate, fit_recording  # noqa: E402
from models.pi import PIModel, thresholds  # noqa: E402
from models.preprocess import Scaling, preprocess  # noqa: E402
from models.recording import read_recording  # noqa: E402


def best_of(fn, repeat=3):
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def main() -> None:
    r = thresholds(50)
    w = np.full(len(r), 1.0 / len(r))
    rng = np.random.default_rng(0)
    s0 = np.zeros(len(r))
    play.play_response(r, np.zeros(10), s0)  # compile (or load the cache) outside the timing
    play.play_weighted(r, w, np.zeros(10), s0)
    print(f"{'samples':>9} {'plain numpy loop':>18} {'numba response':>16} {'numba weighted':>16} {'ratio resp':>11} {'ratio wtd':>10}")
    for n in (100_000, 1_000_000):
        x = np.clip(np.cumsum(rng.normal(0, 0.01, n)), -1, 1)
        t_plain = best_of(lambda: oracles.play_response_numpy(r, x, s0), repeat=1)
        t_resp = best_of(lambda: play.play_response(r, x, s0))
        t_wtd = best_of(lambda: play.play_weighted(r, w, x, s0))
        print(f"{n:>9} {n / t_plain:>14.3g} S/s {n / t_resp:>12.3g} S/s {n / t_wtd:>12.3g} S/s"
              f" {t_plain / t_resp:>10.1f}x {t_plain / t_wtd:>9.1f}x")

    path = ROOT.parent / "shared" / "data" / "bench_identification.csv"
    rec = read_recording(path)
    t_ours = best_of(lambda: fit_recording("pi", rec))
    model = fit_recording("pi", rec)

    def plain_fit():
        # The paper's PI, fitted naively: same preprocessing, Eq. (2) thresholds, per-sample loop, lstsq.
        pre = preprocess(rec.t_s, rec.duty_pct, rec.flow_lpm)
        xs, ys = Scaling.from_data(rec.duty_pct), Scaling.from_data(rec.flow_lpm)
        xu, yu = xs.to_unit(pre.x), ys.to_unit(pre.y)
        rr = thresholds(50, float(np.max(np.abs(xu))))[1:]
        # same start as valvectl's fit (at rest at the first input), so only the model differs
        Y, _ = oracles.play_response_numpy(rr, xu, play.init(rr, xu[0], np.nan))
        ww, *_ = np.linalg.lstsq(Y, yu, rcond=None)
        return PIModel(r=rr, w=ww), xs, ys

    t_plain = best_of(plain_fit)
    plain, xs, ys = plain_fit()
    plain_pred = ys.from_unit(plain.predict(xs.to_unit(rec.duty_pct))[0])
    plain_mae = float(np.mean(np.abs(plain_pred - rec.flow_lpm)))
    ours = evaluate(model, rec.duty_pct, rec.flow_lpm)
    print(f"\nPI fit on {path.name} ({len(rec)} rows, n = 50):")
    print(f"  valvectl fit (numba, constrained lsq): {t_ours * 1e3:8.1f} ms   MAE {ours.mae:.3f} L/min")
    print(f"  plain per-sample loop + lstsq        : {t_plain * 1e3:8.1f} ms   MAE {plain_mae:.3f} L/min")
    print(f"  speed-up {t_plain / t_ours:.1f}x, MAE ratio ours/plain {ours.mae / plain_mae:.3f}")


if __name__ == "__main__":
    main()
