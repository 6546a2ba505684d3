"""Regenerate models/diagnose/margins.json from effect-free plant_sim recordings.

Every detector is run on effect-free recordings (plant_sim's forward model
with no effect word, over seeds x noise levels x excitations; the sensor
offset detector also against the model file). The largest relative
held-out gain each detector reaches there, times the safety factor of
:mod:`models.diagnose.calibrate`, becomes its margin.

    .venv/bin/python bench/calibrate_diagnose.py
"""
from __future__ import annotations

import itertools
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the CLI runs: BLAS threads spin on a shared machine
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402
from diagnose_suite import EXCITATIONS, MATRIX_EXCITATIONS, MODEL_JSON, Case, record  # noqa: E402

from models.diagnose.calibrate import PATH, calibrate, load_margins  # noqa: E402
from models.diagnose.design import fit_baseline, fixed_base  # noqa: E402
from models.diagnose.detectors import reference, test_effect  # noqa: E402
from models.diagnose.folds import make_folds  # noqa: E402
from models.diagnose.signals import work_signals  # noqa: E402
from models.model import load_model  # noqa: E402
from models.diagnose.words import VOCABULARY, WORDS  # noqa: E402
from models.recording import Recording  # noqa: E402

#: Seeds of the calibration recordings: none of the suites' (1-4, 99), so the suites stay held out.
SEEDS = (11, 12, 13)
#: Every open-loop excitation of the concealed suite and of the magnitude x excitation matrix.
CAL_EXCITATIONS = tuple(dict.fromkeys(EXCITATIONS + tuple(e for e in MATRIX_EXCITATIONS if e != "closed_loop")))
NOISES = (0.25, 0.5, 1.0)
#: Noise of the supply gauge (bar) on the effect-free recordings: a steady supply read by a real
#: gauge, so that the supply-pressure detector has something to be calibrated on.
GAUGE_NOISE_BAR = 0.01


def free_gains_one(job) -> dict:
    """Relative held-out gain and folds won of every detector on one effect-free recording."""
    exc, seed, noise = job
    rec = record(Case((), exc, seed, noise))
    gauge = rec.columns["supply_bar"] + np.random.default_rng(seed).normal(0.0, GAUGE_NOISE_BAR, len(rec.t_s))
    rec = Recording(rec.path, {**rec.columns, "supply_bar": gauge})
    sig = work_signals(rec)
    folds = make_folds(sig.t_s)
    out = {}
    margins = load_margins()
    for base in (fit_baseline(sig, folds), fixed_base(load_model(MODEL_JSON), sig)):
        base, before = reference(base, sig, folds)
        for w in WORDS:
            if VOCABULARY[w].applicable(sig, base) or (not base.refit and w != "sensor_offset"):
                continue
            # the exact law is refined where the screen's training error falls by the current margin
            c = test_effect(w, {}, before, base, sig, folds, margins.gain[w])
            out.setdefault(w, []).append((c.gain, c.wins))
    return out


def free_gains(seeds=SEEDS, noises=NOISES, excitations=CAL_EXCITATIONS, workers: int = 2) -> tuple[dict, dict]:
    """Relative held-out gain and folds won of every detector on every effect-free recording."""
    gains = {w: [] for w in WORDS}
    wins = {w: [] for w in WORDS}
    with ProcessPoolExecutor(workers) as ex:
        for out in ex.map(free_gains_one, itertools.product(excitations, seeds, noises)):
            for w, results in out.items():
                gains[w] += [g for g, _ in results]
                wins[w] += [k for _, k in results]
    return gains, wins


def main() -> int:
    start = time.perf_counter()
    gains, wins = free_gains()
    margins = calibrate(gains)
    doc = {"generated_by": "bench/calibrate_diagnose.py", "recordings": "plant_sim effect-free, seeds "
           f"{list(SEEDS)}, noise {list(NOISES)} L/min, excitations {list(CAL_EXCITATIONS)}, supply gauge noise "
           f"{GAUGE_NOISE_BAR} bar",
           **margins.to_dict(),
           "free_max_gain": {w: max(g) if g else None for w, g in gains.items()},
           "free_max_wins": {w: max(v) if v else None for w, v in wins.items()}}
    PATH.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    for w in WORDS:
        g = gains[w]
        print(f"{w:24s} n={len(g):3d} max gain {max(g) if g else float('nan'):+.4f} "
              f"max wins {max(wins[w]) if g else 0} -> margin {margins.gain[w]:.4f}")
    print(f"wrote {PATH} in {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
