"""The identification's timeline: a recording with missed periods on the even grid the valve lived."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.identify.timeline import DAMAGED_UNOBSERVED, STALL_PERIODS, damage, in_gaps, timeline, verdict

RATE = 1000.0


def recording(n, seed):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / RATE
    duty = rng.uniform(0.0, 100.0, n)
    flow = rng.uniform(0.0, 150.0, n)
    phase = np.where(np.arange(n) < n // 2, "sweep", "steps")
    return t, duty, flow, phase


@settings(max_examples=20, deadline=None)
@given(n=st.integers(50, 3000), seed=st.integers(0, 10_000), late=st.floats(0.0, 0.7), early=st.floats(0.0, 0.2))
def test_a_recording_without_missed_periods_maps_row_for_row(n, seed, late, early):
    t, duty, flow, phase = recording(n, seed)
    fresh = np.random.default_rng(seed).random(n) > 0.3
    fresh[0] = True
    # a real clock wakes a little after each deadline (or a hair before)
    jitter = np.random.default_rng(seed + 1).uniform(-early, late, n) / RATE
    jitter[0] = 0.0
    tl = timeline(t + jitter, duty, flow, fresh, phase, RATE)
    assert len(tl.t_s) == n and np.array_equal(tl.row, np.arange(n))
    assert np.array_equal(tl.duty_pct, duty) and np.array_equal(tl.phase, phase) and np.array_equal(tl.fresh, fresh)
    # the readings at their rows' own times, linear between them
    assert np.allclose(tl.flow_lpm, np.interp(tl.t_s, (t + jitter)[fresh], flow[fresh]))
    d = damage(tl, ("sweep",), "steps")
    assert d.missed == 0 and d.stalls == 0 and verdict(d)[0] == "ok"


@settings(max_examples=20, deadline=None)
@given(n=st.integers(200, 3000), seed=st.integers(0, 10_000), stalls=st.lists(st.integers(1, 60), max_size=12))
def test_missed_periods_hold_the_duty_and_are_counted(n, seed, stalls):
    t, duty, flow, phase = recording(n, seed)
    rng = np.random.default_rng(seed)
    keep = np.ones(n, dtype=bool)
    for length in stalls:  # runs of missed periods, never the first or the last row
        a = int(rng.integers(1, n - 1))
        keep[a:min(a + length, n - 1)] = False
    kept = np.flatnonzero(keep)
    tl = timeline(t[keep], duty[keep], flow[keep], np.ones(len(kept), dtype=bool), phase[keep], RATE)
    assert len(tl.t_s) == n and np.array_equal(tl.row, kept)
    # every period has the duty last commanded: the valve held it through the missed ones
    last = kept[np.searchsorted(kept, np.arange(n), side="right") - 1]
    assert np.array_equal(tl.duty_pct, duty[last]) and np.array_equal(tl.phase, phase[last])
    # the flow is read at the rows' own times and linear between them
    assert np.allclose(tl.flow_lpm, np.interp(np.arange(n), kept, flow[keep]))
    d = damage(tl, ("sweep",), "steps")
    runs = np.flatnonzero(np.diff(np.r_[1, keep.astype(int)]) == -1)
    assert d.missed == n - len(kept) and d.stalls == len(runs)
    lengths = np.diff(np.r_[-1, kept]) - 1
    assert d.longest_stall_ms == pytest.approx(lengths.max() * 1e3 / RATE)
    # a gap of more than STALL_PERIODS periods between readings is never scored
    assert np.array_equal(~tl.observed, in_gaps(kept, n, STALL_PERIODS))
    assert (~tl.observed).sum() == sum(g for g in lengths if g + 1 > STALL_PERIODS)


def test_each_row_keeps_the_period_it_was_made_in():
    # the third row woke 0.6 periods late (its period still), the fourth a hair early for the third period
    # (the one after it), the fifth after a missed period
    t = np.array([0.0, 0.001, 0.0026, 0.00274, 0.005])
    tl = timeline(t, np.arange(5.0), np.arange(5.0), np.ones(5, dtype=bool), np.full(5, "sweep"), RATE)
    assert list(tl.row) == [0, 1, 2, 3, 5] and list(tl.duty_pct) == [0, 1, 2, 3, 3, 4]


def test_missed_periods_make_the_recording_degraded_then_unobserved_ones_damaged():
    n = 10_000
    t, duty, flow, phase = recording(n, 0)
    # 12 % of the periods missed in 10 ms stalls: degraded
    keep = np.ones(n, dtype=bool)
    for a in range(100, n - 100, 83):
        keep[a:a + 10] = False
    d = damage(timeline(t[keep], duty[keep], flow[keep], keep[keep], phase[keep], RATE), ("sweep",), "steps")
    assert d.missed_share == pytest.approx(1 - keep.mean())
    assert d.unobserved_fit_share == pytest.approx(1 - keep[: n // 2].mean(), abs=0.01)
    assert verdict(d)[0] == "degraded" and "12% of the periods missed" in verdict(d)[1]
    # the session ran on, but readings came in one period of ten in the steps: damaged
    fresh = np.ones(n, dtype=bool)
    fresh[n // 2:] = np.arange(n - n // 2) % 10 == 0
    d = damage(timeline(t, duty, flow, fresh, phase, RATE), ("sweep",), "steps")
    assert d.missed == 0 and d.unobserved_fit_share == 0.0 and d.unobserved_steps_share > DAMAGED_UNOBSERVED
    assert verdict(d)[0] == "damaged" and "too damaged" in verdict(d)[1]
