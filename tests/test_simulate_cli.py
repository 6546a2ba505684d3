"""`valvectl simulate`: recordings per DESIGN.md, each effect word visible, bad input exits 2."""
import json

import numpy as np
import pytest

from controller.cli import main
from models.recording import read_recording
from plant_sim.effects import EFFECTS


def simulate(tmp_path, name, *extra):
    out = tmp_path / f"{name}.csv"
    rc = main(["simulate", "--protocol", "sines", "--duration", "40", "--rate", "50", "--seed", "3",
               "-o", str(out), *extra])
    assert rc == 0
    return out


@pytest.fixture(scope="module")
def baseline(tmp_path_factory):
    return simulate(tmp_path_factory.mktemp("sim"), "base")


def test_recording_has_the_design_columns(baseline):
    rec = read_recording(baseline)
    assert list(rec.columns) == ["t_s", "duty_pct", "flow_lpm", "supply_bar", "coil_temp_c"]
    assert len(rec) == 2000 and rec.rate_hz == pytest.approx(50.0)


@pytest.mark.parametrize("word", sorted(EFFECTS))
def test_each_effect_word_changes_the_recording(tmp_path, baseline, word):
    with_effect = read_recording(simulate(tmp_path, word, "--effect", word))
    base = read_recording(baseline)
    assert not np.array_equal(with_effect.flow_lpm, base.flow_lpm)
    assert np.array_equal(with_effect.duty_pct, base.duty_pct)


def test_same_seed_same_file(tmp_path, baseline):
    again = simulate(tmp_path, "again")
    assert again.read_bytes() == baseline.read_bytes()


def test_effects_combine(tmp_path, baseline):
    one = read_recording(simulate(tmp_path, "one", "--effect", "sensor_offset=3"))
    two = read_recording(simulate(tmp_path, "two", "--effect", "sensor_offset=3", "--effect", "saturation=100"))
    cap = 100.0 + 3.0 + 6 * 0.5  # saturation + offset + six noise standard deviations
    assert one.flow_lpm.max() > cap + 10.0 and two.flow_lpm.max() < cap


@pytest.mark.parametrize("args, message", [
    (["--effect", "warp=1"], "unknown effect 'warp'"),
    (["--effect", "dead_zone=x"], "not a number"),
    (["--effect", "transport_delay=-1"], "outside"),
    (["--protocol", "nothing"], "neither a protocol"),
    (["--duration", "0"], "--duration"),
    (["--rate", "-5"], "--rate"),
])
def test_bad_input_exits_2_with_one_line(tmp_path, capsys, args, message):
    rc = main(["simulate", "-o", str(tmp_path / "x.csv"), *args])
    err = capsys.readouterr().err
    assert rc == 2 and message in err and err.count("\n") == 1


def test_effect_free_recording_is_fit_by_valvectl_fit_to_the_noise_level(tmp_path):
    rec = tmp_path / "ident.csv"
    assert main(["simulate", "--duration", "600", "--rate", "20", "--seed", "1", "-o", str(rec)]) == 0
    figures = tmp_path / "fit.json"
    assert main(["fit", str(rec), "--model", "pi", "-o", str(tmp_path / "m.json"), "--json", str(figures)]) == 0
    noise_lpm = 0.5  # config/plant.toml, [sensor] noise_lpm
    assert json.loads(figures.read_text())["rmse"] < 1.1 * noise_lpm
