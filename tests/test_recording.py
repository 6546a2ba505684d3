"""Recordings: the CSV of DESIGN.md is read exactly, and every bad input is one clear line, exit 2."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from controller.cli import main
from models.recording import InputError, RecordingWriter, read_recording, write_recording

GOOD = "t_s,duty_pct,flow_lpm,supply_bar,note\n0.0,40,10.5,3.0,a\n0.1,41,11.0,3.0,b\n0.2,42,12.0,2.9,c\n"


def write(tmp_path, text, name="rec.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_good_recording_reads_every_numeric_column_and_keeps_extras(tmp_path):
    rec = read_recording(write(tmp_path, GOOD))
    assert len(rec) == 3
    np.testing.assert_array_equal(rec.duty_pct, [40, 41, 42])
    np.testing.assert_array_equal(rec.get("supply_bar"), [3.0, 3.0, 2.9])
    assert rec.text_columns["note"] == ["a", "b", "c"]
    assert rec.rate_hz == pytest.approx(10.0)


BAD = [
    ("t_s,flow_lpm\n0,1\n", 1, "duty_pct", "missing"),
    ("t_s,duty_pct,flow_lpm\n0,40,1\n0.1,abc,2\n", 3, "duty_pct", "not a number"),
    ("t_s,duty_pct,flow_lpm\n0,40,1\n0.1,41,nan\n", 3, "flow_lpm", "finite"),
    ("t_s,duty_pct,flow_lpm\n0,40,1\n0.1,41,inf\n", 3, "flow_lpm", "finite"),
    ("t_s,duty_pct,flow_lpm\n0,40,1\n0.1,41,2\n0.1,42,3\n", 4, "t_s", "does not increase"),
    ("t_s,duty_pct,flow_lpm\n0,40,1\n0.1,41,2\n0.05,42,3\n", 4, "t_s", "does not increase"),
    ("t_s,duty_pct,flow_lpm\n0,40,1\n0.1,100.5,2\n", 3, "duty_pct", "outside"),
    ("t_s,duty_pct,flow_lpm\n0,-1,1\n", 2, "duty_pct", "outside"),
    ("t_s,duty_pct,flow_lpm\n", 1, None, "header only"),
    ("", 1, None, "empty"),
    ("t_s,duty_pct,flow_lpm\n0,40\n", 2, None, "expected 3 fields"),
    ("t_s,duty_pct,flow_lpm,supply_bar\n0,40,1,x\n", 2, "supply_bar", "not a number"),
]


@pytest.mark.parametrize("text,line,column,words", BAD)
def test_bad_input_names_file_line_and_column(tmp_path, text, line, column, words):
    p = write(tmp_path, text)
    with pytest.raises(InputError) as err:
        read_recording(p)
    msg = str(err.value)
    assert msg.startswith(f"{p}:{line}:")
    if column:
        assert f"'{column}'" in msg
    assert words in msg
    assert "\n" not in msg


@pytest.mark.parametrize("text,line,column,words", BAD)
def test_cli_exits_2_with_one_line_for_bad_input(tmp_path, capsys, text, line, column, words):
    p = write(tmp_path, text)
    code = main(["fit", str(p), "--model", "pi", "-o", str(tmp_path / "m.json")])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and f"{p}:{line}:" in err
    assert not (tmp_path / "m.json").exists()


def test_missing_file_and_bad_arguments_exit_2_without_traceback(tmp_path):
    for args in (["fit", str(tmp_path / "none.csv"), "--model", "pi", "-o", "x.json"],
                 ["fit", "--model", "pi"],
                 ["compare", str(tmp_path / "none.csv"), "--json", "x.json"]):
        proc = subprocess.run([sys.executable, "-m", "controller.cli", *args], capture_output=True, text=True)
        assert proc.returncode == 2
        assert "Traceback" not in proc.stderr
        assert len(proc.stderr.strip().splitlines()) == 1


def test_written_recording_reads_back_exactly(tmp_path):
    t = np.arange(5) * 0.001 + 1000.0
    cols = {"t_s": t, "duty_pct": np.linspace(0, 100, 5), "flow_lpm": np.array([0.1, 1 / 3, 2.5, 1e-7, 199.9])}
    write_recording(tmp_path / "r.csv", cols)
    rec = read_recording(tmp_path / "r.csv")
    for k, v in cols.items():
        np.testing.assert_allclose(rec.columns[k], v, rtol=1e-9, atol=0)


def test_streamed_rows_are_on_disk_before_close(tmp_path):
    p = tmp_path / "run.csv"
    w = RecordingWriter(p, ["t_s", "duty_pct", "flow_lpm", "state"])
    w.write([0.0, 10.0, 1.0, "running"])
    w.write([0.001, 11.0, 1.5, "safe"])
    rec = read_recording(p)  # read while still open: a killed run keeps its rows
    assert len(rec) == 2 and rec.text_columns["state"] == ["running", "safe"]
    w.close()
