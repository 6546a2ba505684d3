"""Sweep candidates from the sweep file (controller/sweep/space.py, spec.py)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.sweep import space
from models.recording import InputError

MODES = ("pid", "ff", "ff+pid", "ff+kf")
KNOWN = {"pid.kp", "pid.ki", "pid.kd", "model", "kf.q_bias_lpm"}


def table(blocks, seed=0):
    return space.candidates(blocks, "s.toml", MODES, KNOWN, seed)


def test_grid_is_every_combination():
    t = table([{"controller": "pid", "pid": {"kp": [0.1, 0.2, 0.4], "ki": [1.0, 10.0], "kd": 0.001}}])
    assert len(t) == 6
    pairs = {(t.settings["pid.kp"][i], t.settings["pid.ki"][i]) for i in range(6)}
    assert pairs == {(a, b) for a in (0.1, 0.2, 0.4) for b in (1.0, 10.0)}
    assert np.all(t.settings["pid.kd"] == 0.001)


@settings(max_examples=30, deadline=None)
@given(st.floats(1e-4, 1.0), st.floats(1.0, 1e3), st.integers(1, 50), st.integers(0, 2**32 - 1))
def test_random_samples_stay_in_their_ranges_and_repeat_with_the_seed(lo, ratio, n, seed):
    hi = lo * ratio
    block = {"controller": "pid", "sample": n, "pid": {"kp": {"log": [lo, hi]}, "kd": {"uniform": [0.0, lo]},
                                                        "ki": [1.0, 5.0]}}
    t = table([block], seed)
    assert len(t) == n
    kp = t.settings["pid.kp"]
    assert np.all((kp >= lo * (1 - 1e-12)) & (kp <= hi * (1 + 1e-12)))
    assert np.all((t.settings["pid.kd"] >= 0) & (t.settings["pid.kd"] <= lo))
    assert set(t.settings["pid.ki"]) <= {1.0, 5.0}
    again = table([block], seed)
    np.testing.assert_array_equal(again.settings["pid.kp"], kp)


def test_log_samples_are_uniform_in_the_logarithm():
    t = table([{"controller": "pid", "sample": 4000, "pid": {"kp": {"log": [0.01, 1.0]}}}])
    frac_low_decade = np.mean(t.settings["pid.kp"] < 0.1)
    assert frac_low_decade == pytest.approx(0.5, abs=0.04)  # 4 sigma of a binomial(4000, 1/2)


def test_blocks_concatenate_and_blank_what_they_do_not_set():
    t = table([{"controller": "pid", "pid": {"kp": [0.1]}},
               {"controller": "ff+kf", "model": ["a.json", "b.json"], "kf": {"q_bias_lpm": 0.01}}])
    assert list(t.controller) == ["pid", "ff+kf", "ff+kf"]
    assert math.isnan(t.settings["pid.kp"][1]) and t.settings["model"][0] == ""
    assert t.row(0) == {"pid.kp": 0.1} and t.row(2) == {"model": "b.json", "kf.q_bias_lpm": 0.01}


@pytest.mark.parametrize("block,field", [
    ({"controller": "pd"}, "controller"),
    ({"controller": "pid", "pid": {"kq": [1.0]}}, "pid.kq"),
    ({"controller": "pid", "pid": {"kp": {"log": [0.0, 1.0]}}, "sample": 3}, "pid.kp"),
    ({"controller": "pid", "pid": {"kp": {"log": [0.1, 1.0]}}}, "pid.kp"),  # a range on a grid
    ({"controller": "pid", "pid": {"kp": []}}, "pid.kp"),
    ({"controller": "pid", "sample": 0}, "sample"),
    ({"controller": "pid", "pid": {"kp": [True]}}, "pid.kp"),
])
def test_bad_blocks_name_the_file_block_and_field(block, field):
    with pytest.raises(InputError) as e:
        table([block])
    msg = str(e.value)
    assert msg.startswith("s.toml: candidates[0]") and field in msg and "\n" not in msg
