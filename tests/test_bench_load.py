"""bench/bench_load.py's reading of a run: which deadlines got no step, and which of them the host's steal covers."""
from __future__ import annotations

import os
import sys

import pytest

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "bench"))


@pytest.fixture(scope="module")
def bl():
    import bench_load

    return bench_load


P = 1e-3


def test_with_catch_up_each_missed_deadline_is_located_and_each_step_late_by_the_rest_of_its_period(bl):
    # deadlines 0..9; 3 and 4 passed whole (the step for 5 started 0.6 periods late); 8 missed; step 9 on time
    t = [0.0, 1.0, 2.0, 5.6, 6.0, 7.95, 9.0]
    missed, late = bl.missed_deadlines([x * P for x in t], P, catch_up=True)
    assert [round(m / P) for m in missed] == [3, 4, 8]
    assert late == pytest.approx([0, 0, 0, 0.6 * P, 0, 0.95 * P, 0], abs=1e-9)
    # without catch_up a step may start periods late: the gaps count, the lateness is not known
    missed, late = bl.missed_deadlines([x * P for x in (0.0, 1.0, 3.0, 4.0)], P, catch_up=False)
    assert [round(m / P) for m in missed] == [2] and late == []


def test_a_deadline_is_stolen_when_its_period_overlaps_a_window_of_steal(bl):
    # steal counter samples (bench clock s, steal ms): it rose between 10.100 and 10.102
    windows = bl.stolen_windows([(10.098, 5.0), (10.100, 5.0), (10.102, 15.0), (10.104, 15.0)])
    assert windows == [pytest.approx((10.100 - bl.STEAL_TICK_S - bl.CLOCK_SLACK_S, 10.102 + bl.CLOCK_SLACK_S))]
    offset = 10.0  # controller t_s + offset = bench clock
    deadlines = [0.0855, 0.0868, 0.1040, 0.1060]  # periods [t, t + 1 ms)
    assert bl.in_windows(deadlines, P, windows, offset) == 2  # 0.0868-0.0878 reaches 10.087; 0.1040 is inside
    assert bl.steal_cover(windows, (10.0, 10.2)) == pytest.approx(100 * (0.002 + 0.010 + 0.006) / 0.2)
    r = {"overruns": 4, "stolen_overruns": 2, "steal_cover_pct": 10.0}
    assert "5x" in bl.enrichment(r)


def test_overruns_in_seconds_without_steal_are_counted_apart(bl):
    # samples every 0.5 s over 3 s from bench time 100; the counter moves only in the second second
    samples = [(100.0 + 0.5 * i, 0.0 if i <= 2 else 10.0) for i in range(7)]
    offset = 100.0
    assert bl.quiet_seconds([0.2, 0.7, 1.3, 2.5], samples, offset) == (2, 3)
