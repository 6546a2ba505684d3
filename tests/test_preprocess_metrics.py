"""Preprocessing (§2.3) and the metrics (§3)."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from models.metrics import metrics
from models.preprocess import CHEBY_RIPPLE_DB, Scaling, lowpass, preprocess


def test_lowpass_keeps_dc_and_passband_without_lag_and_removes_noise():
    rate = 100.0
    t = np.arange(20000) / rate
    slow = 50 + 10 * np.sin(2 * np.pi * 0.2 * t)
    fast = np.sin(2 * np.pi * 30 * t)
    out = lowpass(slow + fast, cutoff_hz=2.0, rate_hz=rate)
    mid = slice(1000, -1000)
    # Passband gain within the Chebyshev ripple, applied twice by filtfilt; DC exactly 1; no lag.
    ripple = 10 ** (2 * CHEBY_RIPPLE_DB / 20) - 1
    np.testing.assert_allclose(out[mid], slow[mid], atol=10 * ripple + 0.01)
    assert abs(np.mean(out[mid]) - 50) < 0.01
    lag = np.argmax(np.correlate(out[mid] - 50, slow[mid] - 50, "full")) - (len(slow[mid]) - 1)
    assert lag == 0


def test_preprocess_downsamples_to_about_ten_hertz():
    t = np.arange(0, 100, 0.01)
    pre = preprocess(t, np.sin(t), np.cos(t))
    assert pre.factor == 10 and pre.rate_hz == pytest.approx(10.0, rel=1e-6)
    assert len(pre.x) == len(t[::10])


@given(lo=st.floats(-1e3, 1e3), span=st.floats(1e-3, 1e3))
def test_scaling_maps_the_data_range_onto_unit_interval_and_back(lo, span):
    x = np.array([lo, lo + span / 3, lo + span])
    s = Scaling.from_data(x)
    u = s.to_unit(x)
    assert u.min() == pytest.approx(-1) and u.max() == pytest.approx(1)
    np.testing.assert_allclose(s.from_unit(u), x, rtol=1e-12, atol=1e-9 * max(1, abs(lo)))


def test_metrics_on_known_errors():
    m = metrics([0, 0, 0, 0], [1, -1, 1, -1])
    assert (m.mae, m.rmse) == (1.0, 1.0)
    m = metrics([1, 2, 3, 4], [2, 4, 6, 8])
    assert m.r == pytest.approx(1.0) and m.mae == pytest.approx(2.5)
    assert metrics([1, 2, 3], [3, 2, 1]).r == pytest.approx(-1.0)
