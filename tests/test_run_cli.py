"""`valvectl run` on the embedded simulated valve: outputs, and bad input as one line with exit 2."""
from __future__ import annotations

import json

import pytest

from controller.cli import main


def test_short_run_writes_summary_record_and_plot(tmp_path, capsys):
    out = {k: tmp_path / f"run.{k}" for k in ("json", "csv", "png")}
    rc = main(["run", "--controller", "ff+pid", "--duration", "0.3", "--json", str(out["json"]),
               "--record", str(out["csv"]), "--plot", str(out["png"])])
    assert rc == 0
    s = json.loads(out["json"].read_text())
    assert s["controller"] == "ff+pid" and s["plant"].startswith("sim")
    assert s["steps"] + s["overruns"] == 300
    lines = out["csv"].read_text().splitlines()
    assert lines[0] == "t_s,ref_lpm,flow_lpm,duty_pct,ff_duty_pct,fb_duty_pct,state,controller,limit_duty_pct,meas_age_ms"
    assert len(lines) == 1 + s["steps"]
    assert out["png"].stat().st_size > 0
    assert "tracking" in capsys.readouterr().out


@pytest.mark.parametrize("text, field", [
    ('controller = "bang-bang"\n', "controller"),
    ("[loop]\nrate_hz = \"fast\"\n", "loop.rate_hz"),
    ("[pid]\nkq = 1.0\n", "pid.kq"),
    ("[plumbing]\nx = 1\n", "plumbing"),
    ("controller = \n", "TOML"),
    ("[kf]\nq_flow_lpm = 1e308\n", "kf.q_flow_lpm"),  # squared by the filter's Riccati equation: inf
])
def test_bad_config_is_one_line_naming_file_and_field(tmp_path, capsys, text, field):
    cfg = tmp_path / "run.toml"
    cfg.write_text(text)
    assert main(["run", "--config", str(cfg), "--duration", "0.1"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(cfg) in err and field in err


def test_bad_arguments_exit_2(capsys):
    with pytest.raises(SystemExit) as e:
        main(["run", "--controller", "mpc"])
    assert e.value.code == 2
    assert main(["run", "--duration", "-1"]) == 2
    assert "--duration" in capsys.readouterr().err


def test_a_plot_suffix_matplotlib_cannot_write_is_bad_input_before_the_run(tmp_path, capsys):
    assert main(["run", "--duration", "0.05", "--plot", str(tmp_path / "run.xyz"),
                 "--json", str(tmp_path / "s.json")]) == 2
    err = capsys.readouterr().err
    assert "--plot" in err and ".png" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "s.json").exists()  # refused before the work
