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
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from diagnose_suite import EXCITATIONS, MODEL_JSON, Case, record  # noqa: E402

from models.diagnose.calibrate import PATH, calibrate  # noqa: E402
from models.diagnose.design import fit_baseline, fixed_base  # noqa: E402
from models.diagnose.detectors import EFFECTS, WORDS, reference, test_effect  # noqa: E402
from models.diagnose.folds import make_folds  # noqa: E402
from models.diagnose.signals import work_signals  # noqa: E402
from models.model import load_model  # noqa: E402

SEEDS = (11, 12, 13)
NOISES = (0.25, 0.5, 1.0)


def free_gains(seeds=SEEDS, noises=NOISES, excitations=EXCITATIONS) -> tuple[dict, dict]:
    """Relative held-out gain and folds won of every detector on every effect-free recording."""
    model = load_model(MODEL_JSON)
    gains = {w: [] for w in WORDS}
    wins = {w: [] for w in WORDS}
    for exc, seed, noise in itertools.product(excitations, seeds, noises):
        sig = work_signals(record(Case((), exc, seed, noise)))
        folds = make_folds(sig.t_s)
        for base in (fit_baseline(sig, folds), fixed_base(model, sig)):
            base, before = reference(base, sig, folds)
            for w in WORDS:
                if EFFECTS[w].applicable(sig, base) or (not base.refit and w != "sensor_offset"):
                    continue
                c = test_effect(w, {}, before, base, sig, folds)
                gains[w].append(c.gain)
                wins[w].append(c.wins)
    return gains, wins


def main() -> int:
    start = time.perf_counter()
    gains, wins = free_gains()
    margins = calibrate(gains)
    doc = {"generated_by": "bench/calibrate_diagnose.py", "recordings": "plant_sim effect-free, seeds "
           f"{list(SEEDS)}, noise {list(NOISES)} L/min, excitations {list(EXCITATIONS)}",
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
