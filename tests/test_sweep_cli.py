"""valvectl sweep: files, bad input, Dask against the local pool, best candidate back in the live loop."""
from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from controller.cli import main
from controller.sweep import metrics, runner
from controller.sweep.spec import load_sweep

ROOT = Path(__file__).resolve().parents[1]
RUN = ROOT / "config" / "run.toml"

SMALL = f"""
run = "{RUN}"
duration_s = 1.0
margins_top = 3
objective = "iae"
heatmap = ["ff_pid.kp", "ff_pid.ki"]
chunk_loops = 8

[profile]
breath_rate_bpm = 40.0

[[variants]]
[[variants]]
supply_bar = 2.6

[[candidates]]
controller = "ff+pid"
sample = 6
ff_pid.kp = {{log = [0.05, 0.5]}}
ff_pid.ki = {{log = [2.0, 50.0]}}

[[candidates]]
controller = "ff+kf"
sample = "grid"
kf.q_bias_lpm = [0.003, 0.03]
model = ["valve_model.json", "valve_model_n10.json"]

[[candidates]]
controller = "pid"
sample = "grid"
pid.kp = [0.1, 0.3]
"""


@pytest.fixture()
def small(tmp_path) -> Path:
    p = tmp_path / "sweep.toml"
    p.write_text(SMALL)
    return p


def read_csv(path):
    with open(path) as fh:
        return list(csv.DictReader(fh))


def test_sweep_writes_table_summary_plot_and_best_config(small, tmp_path, capsys):
    out, js, png, best = (tmp_path / n for n in ("s.csv", "s.json", "p.png", "best.toml"))
    assert main(["sweep", "--config", str(small), "-o", str(out), "--json", str(js), "--plot", str(png),
                 "--best-config", str(best), "--workers", "1", "--report", str(tmp_path / "rep")]) == 0
    rows = read_csv(out)
    assert len(rows) == 1 + 6 + 4 + 2  # the default first, then the file's candidates
    header = list(rows[0])
    figs = list(metrics.NAMES)
    i = header.index("iae")
    assert header[i:i + len(figs)] == figs
    assert header[i + len(figs):i + 2 * len(figs)] == [f"worst_{n}" for n in figs]
    from controller.config import load_run_config

    run = load_run_config(RUN)
    word = run[""]["controller"]
    assert rows[0]["controller"] == word  # the run's own controller, as configured
    assert rows[0]["ff_pid.kp"] == ("" if word != "ff+pid" else format(run["ff_pid"]["kp"], ".6g"))
    for r in rows:
        assert float(r["worst_iae"]) >= float(r["iae"])
    s = json.loads(js.read_text())
    assert s["candidates"] == len(rows) and s["seconds"] > 0
    assert set(s["default"]) >= {"params", *figs} and set(s["best"]) >= {"params", *figs}
    iae = [float(r["iae"]) for r in rows]
    assert s["best"]["iae"] == pytest.approx(min(iae), rel=1e-5)
    assert s["best"]["iae"] <= s["default"]["iae"]
    assert png.read_bytes()[:4] == b"\x89PNG"
    assert "[pid]" in best.read_text()
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "![sweep](sweep.png)" in md and f"## best: {s['best']['params']['controller']}" in md


def test_dask_cluster_gives_the_local_pools_table(small):
    from distributed import LocalCluster

    s = load_sweep(small)
    local = runner.run_sweep(s, workers=2)
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None) as cluster:
        remote = runner.run_sweep(s, scheduler=cluster.scheduler_address)
    assert remote.columns == local.columns
    for c in local.columns:
        np.testing.assert_array_equal(np.array(remote.table[c], dtype=object), np.array(local.table[c], dtype=object))


@pytest.mark.parametrize("edit,field", [
    ("duration_s = 1.0", "duraton_s = 1.0"),
    ('controller = "pid"', 'controller = "pd"'),
    ("pid.kp = [0.1, 0.3]", "pid.kq = [0.1, 0.3]"),
    ("ff_pid.kp = {log = [0.05, 0.5]}", "ff_pid.kp = {log = [0.0, 0.5]}"),
    ("supply_bar = 2.6", "supply_psi = 2.6"),
    ("margins_top = 3", 'margins_top = "3"'),
    ("sample = 6", "sample = -6"),
])
def test_bad_sweep_file_is_one_line_naming_file_and_field_exit_2(small, tmp_path, capsys, edit, field):
    old, new = edit, field
    small.write_text(SMALL.replace(old, new))
    code = main(["sweep", "--config", str(small), "-o", str(tmp_path / "s.csv")])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1 and str(small) in err
    key = new.split("=")[0].strip().split(".")[-1]
    assert key in err or new.split("=")[1].strip().strip('"') in err


def test_a_variant_runs_another_forward_model(small, tmp_path, capsys):
    import dataclasses
    import shutil

    from controller.sweep.spec import plants

    shutil.copy(ROOT / "config" / "valves" / "pvp" / "valve_pi_mod.json", tmp_path / "other.json")
    small.write_text(SMALL + '\n[[variants]]\nmodel = "other.json"   # relative to the sweep file\n')
    s = load_sweep(small)
    nominal, _, other = plants(s.run, s.variants, s.path)
    assert other.model.kind == "pi-mod" and nominal.model.kind != "pi-mod"
    fields = [f.name for f in dataclasses.fields(nominal) if f.name != "model"]
    assert [getattr(other, f) for f in fields] == [getattr(nominal, f) for f in fields]  # the model is all it changes
    small.write_text(SMALL + '\n[[variants]]\nmodel = "missing.json"\n')
    assert main(["sweep", "--config", str(small), "-o", str(tmp_path / "s.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "missing.json" in err


def test_missing_sweep_file_exit_2(tmp_path, capsys):
    assert main(["sweep", "--config", str(tmp_path / "nope.toml"), "-o", str(tmp_path / "s.csv")]) == 2
    assert "no such file" in capsys.readouterr().err


def best_run(small, tmp_path):
    out, js, best = tmp_path / "s.csv", tmp_path / "s.json", tmp_path / "best.toml"
    assert main(["sweep", "--config", str(small), "-o", str(out), "--json", str(js), "--best-config", str(best),
                 "--workers", "1"]) == 0
    return json.loads(js.read_text()), best


def test_best_config_in_the_live_loop_reproduces_the_sweep_iae(small, tmp_path):
    """The best settings written as a run config, run by the live loop on a simulated clock."""
    from controller.config import controller_params, load_run_config, preview_s
    from controller.loop import Loop, ProfileReference, SimClock
    from controller.run_summary import summary
    from controller.transport.sim import SimTransport
    from models.model import load_model
    from plant_sim.plant import Plant, load_plant
    from plant_sim.protocols import BreathProfile

    s, best = best_run(small, tmp_path)
    cfg = load_run_config(best)  # the way `valvectl run --config` reads it
    top = cfg[""]
    assert top["controller"] == s["best"]["params"]["controller"]
    params = controller_params(cfg, top["controller"], load_model(cfg.resolve(top["model"])))
    plant = load_plant(cfg.resolve(top["plant_config"]), effects=cfg["effects"])
    transport = SimTransport(Plant(plant, cfg.loop.rate_hz, seed=top["seed"]), cfg.loop.safe_duty_pct)
    ref = ProfileReference(BreathProfile(**cfg["profile"]).value, preview_s(cfg, "profile"))
    res = Loop(params, transport, ref, cfg.loop, clock=SimClock()).run(top["duration_s"])
    iae = summary(res, top["controller"], "sim")["tracking"]["iae"]
    assert iae == pytest.approx(s["best"]["iae"], rel=0.10)


@pytest.mark.slow
def test_best_config_with_valvectl_run_in_real_time(small, tmp_path):
    s, best = best_run(small, tmp_path)
    js = tmp_path / "run.json"
    subprocess.run([sys.executable, "-m", "controller.cli", "run", "--config", str(best), "--json", str(js)],
                   check=True, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)}, capture_output=True)
    run = json.loads(js.read_text())
    assert run["tracking"]["iae"] == pytest.approx(s["best"]["iae"], rel=0.10)
