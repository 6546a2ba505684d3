"""Every model kind on real measurements from public projects (../shared/data/external).

The levels asserted come from baselines computed here on the same data, not
from figures of a run: a straight line fitted by least squares (the
memoryless, hysteresis-free model) and the signal range.
"""
from __future__ import annotations

import numpy as np
import pytest

from models.fitting import KINDS, evaluate, fit_model, fit_recording
from models.metrics import metrics
from models.recording import read_recording, read_table
from tests.conftest import DATA

EXTERNAL = DATA / "external"


def line_fit(x, y):
    """Metrics of the least-squares straight line ``y ~ x``."""
    return metrics(y, np.polyval(np.polyfit(x, y, 1), x))


@pytest.fixture(scope="module")
def pvp():
    p = EXTERNAL / "pvp_valve_sweep.csv"
    if not p.exists():
        pytest.skip(f"{p} not present")
    return read_recording(p)


@pytest.fixture(scope="module")
def piezo():
    p = EXTERNAL / "piezo_150v_1hz.csv"
    if not p.exists():
        pytest.skip(f"{p} not present")
    tab = read_table(p, ("t_s", "voltage_v", "displacement_um"))
    # 5 kHz for 10 s: every 10th row (500 Hz, 500 per cycle) still resolves the 1 Hz loops.
    return {k: v[::10] for k, v in tab.columns.items()}


@pytest.mark.parametrize("kind", KINDS)
def test_every_model_fits_the_pvp_valve_sweep(kind, pvp):
    # A PWM proportional valve swept 0 -> 100 -> 0 % in 1 % steps: a dead zone, an S-shaped
    # rise and little hysteresis. Every kind holds a straight line (or, for the Preisach
    # kinds, a memoryless curve) as a special case, so none may do worse than the line.
    model = fit_recording(kind, pvp)
    pred, _ = model.predict(pvp.duty_pct)
    assert np.all(np.isfinite(pred))
    m = evaluate(model, pvp.duty_pct, pvp.flow_lpm)
    line = line_fit(pvp.duty_pct, pvp.flow_lpm)
    assert m.rmse <= 1.02 * line.rmse and m.r >= line.r - 0.005
    assert m.mae < 0.15 * np.ptp(pvp.flow_lpm)
    if kind == "preisach":
        # Diagonal relays are steps: a memoryless curve is in the class up to the level
        # spacing (2 % duty, a few L/min at the steepest slope).
        assert m.rmse < 0.25 * line.rmse and m.r > 0.99


@pytest.mark.parametrize("kind", KINDS)
def test_every_model_fits_the_piezo_actuator(kind, piezo):
    # +-150 V at 1 Hz on a piezo actuator: wide loops; a memoryless
    # line misses the loop width, every hysteresis model must beat it.
    t, v, d = piezo["t_s"], piezo["voltage_v"], piezo["displacement_um"]
    model = fit_model(kind, t, v, d, x_name="voltage_v", y_name="displacement_um")
    pred, _ = model.predict(v)
    assert np.all(np.isfinite(pred))
    m = metrics(d, pred)
    line = line_fit(v, d)
    assert m.rmse < line.rmse and m.r > line.r
    assert m.mae < 0.05 * np.ptp(d)
