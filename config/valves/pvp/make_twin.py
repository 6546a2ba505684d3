"""Refit the PVP twin: ``python config/valves/pvp/make_twin.py`` (from the checkout, .venv active).

pi-mod is fitted on the real PVQ31 sweep (../shared/data/external/pvp_valve_sweep.csv)
played twice in a row. One sweep starts the operators at rest and never closes and
reopens the valve again, so it leaves their memory after a closure free: fitted on it
alone, the twin gave 40 L/min at 20 % duty on a second opening where the first gave 0
(RMSE 43.6 L/min on a repeated sweep). A near hysteresis-free valve answers a repeated
sweep as it answered the first, so the repeat pins that memory down.
"""
import os
import subprocess
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
SWEEP = os.path.join(HERE, "..", "..", "..", "..", "shared", "data", "external", "pvp_valve_sweep.csv")


def main() -> None:
    d = np.genfromtxt(SWEEP, delimiter=",", names=True)
    cols = d.dtype.names
    once = np.column_stack([d[c] for c in cols])
    twice = np.concatenate([once, once])
    period_s = once[-1, 0] - once[0, 0] + np.median(np.diff(once[:, 0]))
    twice[len(once):, 0] += period_s
    with tempfile.TemporaryDirectory() as tmp:
        rec = os.path.join(tmp, "pvp_twice.csv")
        np.savetxt(rec, twice, delimiter=",", header=",".join(cols), comments="", fmt="%.6g")
        subprocess.run([sys.executable, "-m", "controller.cli", "fit", rec, "--model", "pi-mod",
                        "-o", os.path.join(HERE, "valve_pi_mod.json")], check=True)


if __name__ == "__main__":
    main()
