"""Shared fixtures: paths to the shared data and small synthetic recordings; the real-time group."""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the CLI runs (controller/cli.py)

from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("VALVECTL_SHARED", ROOT.parent / "shared"))
DATA = SHARED / "data"


@pytest.fixture(scope="session")
def bench_identification() -> Path:
    p = DATA / "bench_identification.csv"
    if not p.exists():
        pytest.skip(f"{p} not present")
    return p


@pytest.fixture(scope="session")
def bench_validation() -> Path:
    p = DATA / "bench_validation.csv"
    if not p.exists():
        pytest.skip(f"{p} not present")
    return p


# Modules whose tests run real-time processes against each other (controller, valve-node, identify,
# monitor, Zenoh peers, a sweep's workers killed within a grace time). Under `make test` (pytest-xdist,
# two workers) they are one unit of work: one worker runs them one after the other, as the serial suite
# did, while the other takes the CPU-bound tests (two of them at once would be two 1 kHz loops spinning
# on a 2-core machine beside the other worker).
REALTIME_MODULES = frozenset({
    "test_cli_consistency", "test_identify_zenoh", "test_monitor", "test_security", "test_sweep_kill",
    "test_trigger", "test_zenoh", "test_zenoh_hostile", "test_zenoh_sched",
})


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """``--dist loadgroup`` with REALTIME_MODULES as one group, every other test on its own.

    The group is told by the test's file, not by an ``xdist_group`` mark: xdist 3.8 carries marks to the
    scheduler by appending them to node ids, which pytest 9.2's node ids no longer take (xdist #1386).
    """
    if config.getvalue("dist") != "loadgroup":
        return None
    from xdist.scheduler import LoadGroupScheduling

    class RealtimeGroup(LoadGroupScheduling):
        def _split_scope(self, nodeid: str) -> str:
            if Path(nodeid.split("::", 1)[0]).stem in REALTIME_MODULES:
                return "realtime"
            return super()._split_scope(nodeid)

    return RealtimeGroup(config, log)


def growing_sine(n: int = 4000, lo: float = 38.0, hi: float = 72.0, cycles: float = 8.0) -> np.ndarray:
    """Duty (%) like the paper's Fig. 2: a sinusoid of growing amplitude around the middle."""
    k = np.arange(n)
    mid, half = (hi + lo) / 2, (hi - lo) / 2
    return mid + half * (0.1 + 0.9 * k / (n - 1)) * np.sin(2 * np.pi * cycles * k / n)
