"""Pareto front and heatmap of a sweep (controller/sweep/plot.py)."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.sweep.plot import heatmap_response, pareto_front, sweep_plot, unit_of, winner_heatmap, winner_settings

pts = st.lists(st.tuples(st.floats(0, 100), st.floats(0, 100)), min_size=1, max_size=60)


def dominated(i, a, b):
    return np.any((a <= a[i]) & (b <= b[i]) & ((a < a[i]) | (b < b[i])))


@settings(max_examples=60, deadline=None)
@given(pts)
def test_front_is_exactly_the_non_dominated_points(p):
    a, b = np.array(p).T
    front = set(pareto_front(a, b).tolist())
    for i in range(len(a)):
        if i in front:
            assert not dominated(i, a, b)
        else:  # dominated, or a duplicate of a front point
            assert dominated(i, a, b) or any(a[j] == a[i] and b[j] == b[i] for j in front)


def test_front_skips_non_finite_points():
    a = np.array([1.0, np.inf, 0.5, np.nan])
    b = np.array([1.0, 0.1, 2.0, 0.0])
    assert pareto_front(a, b).tolist() == [2, 0]


def test_heatmap_cell_holds_the_least_value_of_its_grid_point():
    kp, ki = np.meshgrid([0.1, 0.2, 0.4], [1.0, 10.0, 100.0], indexing="ij")
    kp, ki = np.repeat(kp.ravel(), 2), np.repeat(ki.ravel(), 2)
    f = np.arange(len(kp), dtype=float)[::-1]
    h = heatmap_response(kp, ki, f, "kp", "ki")
    assert h.value.shape == (3, 3) and h.y_log and not h.x_log
    for x, y, v in zip(kp, ki, f):
        ix = np.searchsorted(h.x_edges, x) - 1
        iy = np.searchsorted(h.y_edges, y) - 1
        assert h.value[iy, ix] <= v


def test_sweep_plot_returns_a_figure_without_switching_the_backend(tmp_path):
    import matplotlib

    backend = matplotlib.get_backend()
    rng = np.random.default_rng(0)
    n = 50
    table = {"controller": np.array(["pid", "ff+pid"] * 25), "iae": rng.uniform(0.1, 1, n),
             "duty_tv": rng.uniform(10, 100, n)}
    h = heatmap_response(rng.uniform(0.01, 1, n), rng.uniform(1, 100, n), table["iae"], "kp", "ki")
    fig = sweep_plot(table, "iae", heat=h, default_index=0, best_index=int(np.argmin(table["iae"])))
    assert len(fig.axes) == 3  # front, heatmap, colour bar
    out = tmp_path / "p.png"
    fig.savefig(out)
    assert out.read_bytes()[:4] == b"\x89PNG" and matplotlib.get_backend() == backend


def test_heatmap_maps_the_winning_words_own_settings_with_units():
    """The configured pair belongs to ff+pid; ff+kf wins: the map shows ff+kf's settings over ff+kf's candidates."""
    rng = np.random.default_rng(1)
    n = 40
    word = np.array(["ff+pid"] * n + ["ff+kf"] * n)
    kp = np.concatenate([rng.uniform(0.1, 1, n), [None] * n])
    qf = np.concatenate([[None] * n, rng.uniform(0.5, 5, n)])
    qb = np.concatenate([[None] * n, rng.uniform(0.005, 0.1, n)])
    iae = np.concatenate([rng.uniform(0.5, 1, n), rng.uniform(0.1, 0.4, n)])
    table = {"controller": word, "ff_pid.kp": kp, "ff_pid.ki": kp, "kf.q_flow_lpm": qf, "kf.q_bias_lpm": qb,
             "iae": iae}
    best = int(np.argmin(iae))
    assert set(winner_settings(table, best, ("ff_pid.kp", "ff_pid.ki"))) == {"kf.q_flow_lpm", "kf.q_bias_lpm"}
    h = winner_heatmap(table, "iae", best, ("ff_pid.kp", "ff_pid.ki"))
    assert "ff+kf" in h.x_name and "(L/min)" in h.x_name
    assert np.nanmin(h.value) == iae[best]
    assert unit_of("ff_pid.ki") == "% per (L/min s)" and unit_of("valve.tau_s") == "s"
