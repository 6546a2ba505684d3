"""Duty protocols and breath profiles."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from models.recording import InputError
from plant_sim.protocols import (PROTOCOLS, BreathProfile, paper_identification, protocol, ramps,
                                 random_holds, steps)


@pytest.mark.parametrize("name", sorted(PROTOCOLS))
def test_every_protocol_has_the_asked_length_and_stays_in_0_100(name):
    d = protocol(name, 50.0, 77.0, seed=1)
    assert len(d) == round(77.0 * 50.0)
    assert np.all((d >= 0.0) & (d <= 100.0)) and np.all(np.isfinite(d))


@settings(max_examples=10, deadline=None)
@given(st.floats(300.0, 2400.0), st.sampled_from([10.0, 20.0, 100.0]))
def test_identification_signal_follows_fig2(duration, rate):
    d = paper_identification(rate, duration)
    assert d.min() == 38.0 and d.max() == 72.0
    assert np.max(np.abs(np.diff(d))) * rate <= 0.4 + 1e-12  # at most 0.4 % duty per second
    # extremes grow away from the middle: a sinusoid of growing amplitude
    dd = np.diff(d)
    turns = np.nonzero(np.sign(dd[1:]) * np.sign(dd[:-1]) < 0)[0] + 1
    amp = np.abs(d[turns] - 55.0)
    assert len(amp) >= 3 and np.all(np.diff(amp) > 0)


def test_steps_hold_each_level():
    d = steps(10.0, 20.0, levels_pct=(40.0, 60.0), hold_s=5.0)
    assert np.array_equal(d, np.repeat([40.0, 60.0, 40.0, 60.0], 50))


def test_ramps_keep_their_rates():
    rates = (1.0, 5.0)
    d = ramps(100.0, 60.0, lo_pct=40.0, hi_pct=60.0, rates_pct_s=rates, hold_s=1.0)
    slopes = np.abs(np.diff(d)) * 100.0
    moving = slopes[slopes > 0]
    assert np.allclose(np.unique(np.round(moving, 9)), rates)


def test_random_holds_reproduce_by_seed():
    a, b, c = (random_holds(20.0, 60.0, seed=s) for s in (3, 3, 4))
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert np.all((a >= 38.0) & (a <= 72.0))


def test_protocol_from_csv_interpolates_and_bad_files_fail(tmp_path):
    f = tmp_path / "p.csv"
    f.write_text("t_s,duty_pct\n0,40\n1,50\n3,50\n")
    d = protocol(str(f), 10.0)
    assert d[0] == 40.0 and d[5] == pytest.approx(45.0) and d[-1] == 50.0 and len(d) == 30
    assert len(protocol(str(f), 10.0, 5.0)) == 50
    f.write_text("t_s,duty_pct\n0,40\n1,140\n")
    with pytest.raises(InputError, match="p.csv:3: column 'duty_pct'"):
        protocol(str(f), 10.0)
    with pytest.raises(InputError, match="neither a protocol"):
        protocol("no_such_protocol", 10.0)


@pytest.mark.parametrize("kind", ["square", "ramp", "sine"])
def test_breath_profile_timing(kind):
    b = BreathProfile(kind, peak_lpm=50.0, breath_rate_bpm=20.0, ie_ratio=0.5, rise_s=0.0, base_lpm=2.0)
    t = np.arange(0.0, 12.0, 0.001)
    v = b.value(t)
    assert np.allclose(b.value(t + b.period_s), v)  # periodic at the breath rate
    insp = v > 2.0
    assert np.mean(insp) == pytest.approx(0.5 / 1.5, abs=0.01)  # I:E = 1:2
    assert v.max() == pytest.approx(50.0, rel=1e-3) and v.min() == 2.0
    assert all(b.value(x) == y for x, y in zip(t[::997], v[::997]))  # scalar and array agree


def test_square_is_constant_ramp_decelerates_sine_peaks_mid_inspiration():
    t = np.linspace(0.1, 0.9, 50)  # inside the first inspiration (ti = 4/3 s at 15 bpm, 1:2)
    sq = BreathProfile("square", peak_lpm=40.0).value(t)
    assert np.all(sq == 40.0)
    rp = BreathProfile("ramp", peak_lpm=40.0, end_fraction=0.25, rise_s=0.0)
    assert np.all(np.diff(rp.value(t)) < 0)
    assert rp.value(rp.inspiration_s - 1e-9) == pytest.approx(10.0, rel=1e-6)
    sn = BreathProfile("sine", peak_lpm=40.0)
    assert sn.value(sn.inspiration_s / 2) == pytest.approx(40.0)


def test_breath_profile_rejects_bad_settings():
    with pytest.raises(InputError, match="kind"):
        BreathProfile("triangle")
    with pytest.raises(InputError, match="breath_rate_bpm"):
        BreathProfile(breath_rate_bpm=0.0)
