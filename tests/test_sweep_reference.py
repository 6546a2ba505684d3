"""The compiled laws give the rows the numpy laws gave (tests/data/sweep_reference: commit a3541a9, plus the law
changes made since, written in numpy as patches of it)."""
from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from controller.sweep import runner, spec

HERE = Path(__file__).parent / "data" / "sweep_reference"


def test_sweep_rows_equal_the_numpy_laws_rows_to_1e_9():
    ref = json.loads((HERE / "reference.json").read_text())
    r = runner.run_sweep(spec.load_sweep(HERE / "sweep.toml"), workers=1)
    assert r.columns == ref["columns"]
    figures = set(runner.figure_columns(r))
    for c in r.columns:
        for i, (got, want) in enumerate(zip(r.table[c], ref["table"][c], strict=True)):
            if c not in figures and not isinstance(want, float):
                assert got == want, (c, i)
            elif c not in figures:
                # A candidate's gains come from numpy's grid functions, whose last bit moves between releases
                # (numpy 2.4.6: one ulp on a geomspace point): inputs equal to 1e-12, not bit for bit.
                assert float(got) == pytest.approx(want, rel=1e-12), (c, i)
            elif want is None:
                assert got is None or math.isnan(got), (c, i)
            else:
                assert float(got) == pytest.approx(want, rel=1e-9, abs=1e-300), (c, i)
