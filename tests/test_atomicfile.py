"""Atomic writes: old or new content, never a part, and no temporary file left by a kill (even SIGKILL)."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from models.atomicfile import atomic_open
from tests.zenoh_helpers import ROOT

KILL_IN_THE_MIDDLE = """
import os, signal, sys
from models.atomicfile import atomic_open
# Ctrl-C as an interactive writer gets it: a child of a background job starts with SIGINT ignored
signal.signal(signal.SIGINT, signal.default_int_handler)
with atomic_open(sys.argv[1]) as fh:
    fh.write("new, half written")
    fh.flush()
    os.kill(os.getpid(), int(sys.argv[2]))
"""


def leftovers(folder) -> list[str]:
    return sorted(n for n in os.listdir(folder) if ".tmp" in n)


def test_replaces_the_file_and_an_error_keeps_the_old_one(tmp_path):
    p = tmp_path / "m.json"
    with atomic_open(p) as fh:
        fh.write("old")
    with pytest.raises(RuntimeError):
        with atomic_open(p) as fh:
            fh.write("new, half written")
            raise RuntimeError("the writer failed")
    assert p.read_text() == "old"
    with atomic_open(p, "wb") as fh:
        fh.write(b"new")
    assert p.read_bytes() == b"new"
    assert leftovers(tmp_path) == []


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL, signal.SIGINT], ids=["TERM", "KILL", "INT"])
def test_a_writer_killed_mid_write_leaves_the_old_file_and_no_temporary(tmp_path, sig):
    p = tmp_path / "m.json"
    p.write_text("old")
    r = subprocess.run([sys.executable, "-c", KILL_IN_THE_MIDDLE, str(p), str(int(sig))], cwd=ROOT,
                       capture_output=True, text=True, timeout=60)
    assert r.returncode != 0
    assert p.read_text() == "old"
    assert leftovers(tmp_path) == []


def test_the_next_write_sweeps_temporaries_of_dead_writers_only(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True).stdout.strip()
    stale, live = tmp_path / f".m.json.tmp{dead}", tmp_path / f".m.json.tmp{os.getppid()}"
    other = tmp_path / f".other.json.tmp{dead}"
    for f in (stale, live, other):
        f.write_text("x")
    with atomic_open(tmp_path / "m.json") as fh:
        fh.write("new")
    assert not stale.exists() and live.exists() and other.exists()


def test_a_killed_fit_leaves_no_temporary_beside_the_model(tmp_path, bench_identification):
    """The fit killed at several moments of its run (loading, fitting, writing): never a temporary."""
    out = tmp_path / "model.json"
    for delay_s in (0.5, 2.0, 4.0):
        p = subprocess.Popen([sys.executable, "-m", "controller.cli", "fit", str(bench_identification), "--model",
                              "pi", "-o", str(out)], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(delay_s)
        p.send_signal(signal.SIGKILL)
        p.wait(60)
        assert leftovers(tmp_path) == []


def test_text_and_figure_writers_go_through_atomic_open(tmp_path):
    import matplotlib.figure

    from models.atomicfile import save_figure_atomic, write_text_atomic

    write_text_atomic(tmp_path / "report.md", "# title\n")
    fig = matplotlib.figure.Figure()
    fig.add_subplot().plot([0, 1], [1, 0])
    save_figure_atomic(fig, tmp_path / "f.png", dpi=20)
    save_figure_atomic(fig, tmp_path / "f.svg")
    assert (tmp_path / "report.md").read_text() == "# title\n"
    assert (tmp_path / "f.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"  # the format follows the suffix
    assert b"<svg" in (tmp_path / "f.svg").read_bytes()[:400]
    with pytest.raises(ValueError):  # a figure that cannot be saved leaves nothing
        save_figure_atomic(fig, tmp_path / "g.nosuchformat")
    assert not (tmp_path / "g.nosuchformat").exists() and leftovers(tmp_path) == []
