"""Plots the python-control way (compute returns data, ``*_plot(result, ax=None)`` returns the figure,
results have ``.plot()``, no global backend switch) and the ``--report DIR`` of run and compare."""
from __future__ import annotations

import numpy as np
import pytest
from matplotlib.figure import Figure

from controller.cli import main
from models.compare import compare_response, write_compare_report
from models.recording import Recording
from plant_sim.plant import Plant, load_plant
from plant_sim.protocols import protocol


@pytest.fixture(autouse=True)
def backend_untouched():
    import matplotlib

    before = matplotlib.get_backend()
    yield
    assert matplotlib.get_backend() == before


def test_run_report_and_plot(tmp_path, capsys):
    rep = tmp_path / "rep"
    assert main(["run", "--controller", "ff+pid", "--duration", "1.2", "--report", str(rep),
                 "--inject", "supply_bar=0.3@0.5"]) == 0
    md = (rep / "report.md").read_text()
    assert "![run](run.png)" in md and (rep / "run.png").read_bytes()[:4] == b"\x89PNG"
    assert "supply_low" in md and "steady MAE" in md


def test_run_plot_draws_into_given_axes_and_splits_the_duty():
    from controller.config import load_run_config, preview_s, supervisor
    from controller.loop import Loop, ProfileReference, SimClock
    from controller.run_summary import RunResult, run_plot
    from controller.transport.sim import SimTransport
    from models.model import load_model
    from plant_sim.protocols import BreathProfile

    cfg = load_run_config("config/run.toml")
    model = load_model(cfg.resolve(cfg[""]["model"]))
    pp = load_plant(cfg.resolve(cfg[""]["plant_config"]), effects=cfg["effects"])
    loop = Loop(supervisor(cfg, "ff+pid", model), SimTransport(Plant(pp, 1000.0)),
                ProfileReference(BreathProfile(**cfg["profile"]).value, preview_s(cfg, "profile")), cfg.loop,
                clock=SimClock())
    res = RunResult(loop.run(1.2), "ff+pid", "sim")
    c = res.loop.columns
    np.testing.assert_allclose(c["ff_duty_pct"] + c["fb_duty_pct"] + c["limit_duty_pct"], c["duty_pct"], atol=1e-9)
    # the start-up clamp is the limit's, not the feedback's: the feedback law never asks for -50 %
    assert c["limit_duty_pct"].min() < -1.0 or c["limit_duty_pct"].max() > 1.0
    fig = res.plot()
    assert isinstance(fig, Figure) and len(fig.axes) == 3
    assert fig.axes[2].get_yscale() == "symlog"
    mine = Figure()
    axes = mine.subplots(3, 1)
    assert run_plot(c, axes) is mine and all(a.lines for a in axes)


def synthetic(seconds, seed):
    pp = load_plant("config/plant.toml")
    duty = protocol("random_holds", 100.0, seconds, seed=seed)
    out = Plant(pp, 100.0, seed=seed).simulate(duty)
    return Recording(f"synthetic{seed}", {k: out[k] for k in ("t_s", "duty_pct", "flow_lpm")})


def test_compare_plot_shows_validation_and_inverse_checks(tmp_path):
    comp = compare_response(synthetic(40, 1), synthetic(20, 2), kinds=("pi",))
    fig = comp.plot()
    assert isinstance(fig, Figure)
    titles = " ".join(a.get_title() for a in fig.axes)
    assert "validation" in titles and "inverse" in titles
    assert comp.inverse_duty_pct.shape == comp.recording.t_s.shape
    path = write_compare_report(comp, tmp_path / "rep")
    md = path.read_text()
    assert "Table 1" in md and "![compare](compare.png)" in md and "val MAE" in md
