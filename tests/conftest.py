"""Shared fixtures: paths to the shared data and small synthetic recordings."""
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


def growing_sine(n: int = 4000, lo: float = 38.0, hi: float = 72.0, cycles: float = 8.0) -> np.ndarray:
    """Duty (%) like the paper's Fig. 2: a sinusoid of growing amplitude around the middle."""
    k = np.arange(n)
    mid, half = (hi + lo) / 2, (hi - lo) / 2
    return mid + half * (0.1 + 0.9 * k / (n - 1)) * np.sin(2 * np.pi * cycles * k / n)
