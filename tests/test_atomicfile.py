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
