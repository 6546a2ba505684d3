"""One behaviour across verbs: default configuration paths, --duration 0, Ctrl-C, progress that changes nothing."""
from __future__ import annotations

import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from controller.cli import main

zenoh = pytest.importorskip("zenoh")

from tests.zenoh_helpers import ROOT, client_session, free_port, wait_for  # noqa: E402


def test_default_configs_resolve_from_the_checkout_outside_it(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)  # no config/ here: every verb takes the checkout's
    assert main(["run", "--duration", "0.05", "--controller", "pid"]) == 0
    assert main(["simulate", "--duration", "1", "-o", "rec.csv"]) == 0
    # a config/ in the working directory wins over the checkout's
    (tmp_path / "config").mkdir()
    (tmp_path / "config" / "run.toml").write_text('controller = "bang"\n')
    assert main(["run", "--duration", "0.05"]) == 2
    assert "bang" in capsys.readouterr().err


def test_chunked_simulation_with_progress_is_the_same_recording():
    from controller.commands import simulate as S
    from plant_sim.plant import Plant, load_plant
    from plant_sim.protocols import protocol

    pp = load_plant("config/plant.toml", {"supply_pressure": 0.1, "transport_delay": 0.013, "creep": 0.05})
    duty = protocol("random_holds", 100.0, 30, seed=1)
    whole = Plant(pp, 100.0, seed=3).simulate(duty)
    chunk, S.CHUNK = S.CHUNK, 777
    try:
        parts = S.simulate_with_progress(pp, 100.0, 3, duty)
    finally:
        S.CHUNK = chunk
    assert set(parts) == set(whole)
    for k in whole:
        np.testing.assert_array_equal(parts[k], whole[k])


def test_valve_node_prints_its_summary_on_ctrl_c_and_runs_until_interrupted_with_duration_0():
    ep = f"tcp/127.0.0.1:{free_port()}"
    node = subprocess.Popen([sys.executable, "-m", "controller.cli", "valve-node", "--listen", ep, "--connect", ep,
                             "--duration", "0"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    with client_session(ep) as s:  # running once it publishes its flow
        meas = s.declare_subscriber("vent/valve/insp/meas/flow", zenoh.handlers.RingChannel(4))
        wait_for(lambda: meas.try_recv() is not None, "the valve node publishing", (node,))
    time.sleep(1.5)  # and still running later (0 = until interrupted)
    assert node.poll() is None
    node.send_signal(signal.SIGINT)
    out, err = node.communicate(timeout=60)
    assert node.returncode == 0, err
    assert out.startswith("valve-node:") and "steps" in out and "Traceback" not in err


def test_negative_durations_are_bad_input(capsys):
    for verb in (["valve-node"], ["monitor"], ["run"]):
        assert main([*verb, "--duration", "-1"]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "--duration" in err


@pytest.mark.parametrize("argv, flag", [
    (["run", "--json", "{bad}/s.json"], "--json"),
    (["run", "--plot", "{bad}/p.png"], "--plot"),
    (["run", "--record", "{bad}/r.csv"], "--record"),
    (["run", "--report", "{bad}/rep"], "--report"),
    (["monitor", "--record", "{bad}/m.csv"], "--record"),
    (["sweep", "-o", "{bad}/s.csv"], "--output"),
    (["sweep", "-o", "{ok}/s.csv", "--report", "{bad}/rep"], "--report"),
    (["compare", "rec.csv", "--json", "{bad}/t.json"], "--json"),
])
def test_unwritable_outputs_are_bad_input_before_any_work(tmp_path, capsys, argv, flag):
    blocker = tmp_path / "file"
    blocker.write_text("")  # a file where a folder should be
    args = [a.format(bad=blocker, ok=tmp_path) for a in argv]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and flag in err and str(blocker) in err
