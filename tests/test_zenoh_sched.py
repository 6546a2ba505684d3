"""Zenoh's I/O threads inherit the scheduling the session is opened under ([zenoh] io_nice / io_priority)."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

from tests.zenoh_helpers import ROOT

pytest.importorskip("zenoh")

PROBE = """
import os, sys, time
from controller.config import load_run_config
from controller.transport.zenoh import open_session
cfg = load_run_config(sys.argv[1])
s = open_session(cfg, [sys.argv[2]], [], "controller")
time.sleep(0.2)
for t in os.listdir("/proc/self/task"):
    comm = open(f"/proc/self/task/{t}/comm").read().strip()
    st = open(f"/proc/self/task/{t}/stat").read().rsplit(")", 1)[1].split()
    print(comm, st[16], st[38], os.getpriority(os.PRIO_PROCESS, 0))
s.close()
"""


def threads(tmp_path, **zenoh_keys) -> list[tuple[str, int, int, int]]:
    from tests.zenoh_helpers import free_port

    text = open(os.path.join(ROOT, "config", "run.toml")).read()
    for k, v in zenoh_keys.items():
        text = "\n".join(f"{k} = {v}" if line.startswith(f"{k} =") else line for line in text.splitlines())
    cfg = os.path.join(ROOT, "config", f".test_sched_{os.getpid()}.toml")
    with open(cfg, "w") as fh:
        fh.write(text)
    try:
        # the probe starts under the normal scheduler at nice 0, whatever the suite runs under (chrt -i, nice)
        out = subprocess.run([sys.executable, "-c", PROBE, cfg, f"tcp/127.0.0.1:{free_port()}"], cwd=ROOT,
                             capture_output=True, text=True, timeout=60,
                             preexec_fn=lambda: (os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0)),
                                                 os.setpriority(os.PRIO_PROCESS, 0, 0)))
    finally:
        os.remove(cfg)
    assert out.returncode == 0, out.stderr
    return [(c, int(n), int(p), int(main)) for c, n, p, main in (line.split() for line in out.stdout.splitlines())]


@pytest.mark.skipif(os.geteuid() != 0, reason="raising priority needs root or CAP_SYS_NICE")
def test_io_threads_get_the_configured_nice_and_the_opening_thread_gets_its_own_back(tmp_path):
    rows = threads(tmp_path, io_nice=-7, io_priority=0)
    zenoh_threads = [r for r in rows if r[0].split("-")[0] in ("app", "net", "acc", "rx", "tx")]
    assert zenoh_threads and all(n == -7 and policy == 0 for _, n, policy, _ in zenoh_threads)
    assert all(main == 0 for *_, main in rows)  # the thread that opened the session is back at nice 0


@pytest.mark.skipif(os.geteuid() != 0, reason="SCHED_FIFO needs root or CAP_SYS_NICE")
def test_io_priority_puts_them_under_sched_fifo(tmp_path):
    rows = threads(tmp_path, io_nice=0, io_priority=5)
    zenoh_threads = [r for r in rows if r[0].split("-")[0] in ("app", "net", "acc", "rx", "tx")]
    assert zenoh_threads and all(policy == os.SCHED_FIFO for _, _, policy, _ in zenoh_threads)
