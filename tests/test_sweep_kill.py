"""A sweep killed with SIGTERM or SIGKILL leaves no worker process behind (they would burn the loop's cores)."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from tests.zenoh_helpers import ROOT, wait_for

GRACE_S = 2.0  # the bound: no worker left this long after the kill


def children(pid: int) -> list[int]:
    out = []
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                with open(f"/proc/{d}/stat") as fh:
                    fields = fh.read().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                out.append(int(d))
    return out


def alive(pid: int) -> bool:
    """Running or sleeping; a zombie (dead, not yet reaped by whoever adopted it) burns nothing."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] not in ("Z", "X")
    except OSError:
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL], ids=["SIGTERM", "SIGKILL"])
def test_a_killed_sweep_leaves_no_worker(tmp_path, sig):
    p = subprocess.Popen([sys.executable, "-m", "controller.cli", "sweep", "--workers", "2", "-o",
                          str(tmp_path / "sweep.csv")], cwd=ROOT, stdout=subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL)
    workers: list[int] = []
    try:
        wait_for(lambda: len(children(p.pid)) >= 2, "the sweep's two workers", (p,))
        workers = children(p.pid)
        p.send_signal(sig)
        p.wait(30)
        t_kill = time.monotonic()
        while any(alive(w) for w in workers) and time.monotonic() - t_kill < GRACE_S:
            time.sleep(0.02)
        assert not [w for w in workers if alive(w)]
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
        for w in workers + children(p.pid):  # the test never leaves a worker behind, even when it fails
            if alive(w):
                os.kill(w, signal.SIGKILL)


def test_a_worker_whose_parent_is_already_gone_exits_at_once():
    """The race: the parent dies before the worker's initializer runs (getppid no longer the parent)."""
    r = subprocess.run([sys.executable, "-c", "from controller.sweep.distributed import die_with_parent; "
                        "die_with_parent(-1); print('survived')"], cwd=ROOT, capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 1 and "survived" not in r.stdout
