"""The mutation battery (:mod:`tests.mutations`): every part of the shipped files broken mechanically.

``make test`` runs the cases that once failed (in-process, fast); the slow
suite runs a spread sample of the whole battery in forked children with a
timeout. Exit 0 is allowed there (whether a mutated value is legal is for a
person to judge); a traceback, several lines or a hang never are.
"""
from __future__ import annotations


import pytest

from tests import mutations
from tests.test_fuzz import ROOT, assert_clean, cli


def _case(name: str):
    return next(c for c in mutations.cases(only=name) if c.name == name)


def _materialized(case, tmp_path) -> list[str]:
    from tests.battery import _materialize

    return _materialize(case, str(tmp_path), str(ROOT))


@pytest.mark.parametrize("name", [
    "toml/run.toml/utf32/run",                      # UnicodeDecodeError out of tomllib
    "toml/sweep.toml/latin1/sweep",
    "toml/sweep.toml/candidates.valve.tau_s[0]=int_overflow/sweep",  # 10**23 in numpy's isfinite
    "json/valves/pvp/valve_pi_mod.json/inverse.params.forward.w.0=negative/diagnose",  # NotInvertible
    "json/valves/pvp/valve_pi_mod.json/inverse.params.forward.g.12=negative/diagnose",  # ValueError
    "toml/run.toml/profile.peak_lpm=bool/run",      # accepted as 1.0
    "toml/run.toml/valve_node.command_timeout_ms=huge/valve-node",  # 1e308 ms: the node never closes
])
def test_once_failing_mutants_end_in_one_line(name, tmp_path):
    argv = _materialized(_case(name), tmp_path)
    code, err = cli(argv)
    assert_clean(code, err, argv)
    assert code == 2, err


def test_the_battery_breaks_every_input_kind_and_verb():
    cases = mutations.cases()
    assert len(cases) > 500
    kinds = {c.name.split("/")[0] for c in cases}
    assert kinds == {"toml", "json", "csv", "option"}
    verbs = {c.argv[0] for c in cases}
    assert verbs >= {"fit", "compare", "simulate", "run", "valve-node", "sweep", "diagnose", "monitor", "certs",
                     "identify"}


@pytest.mark.slow
def test_mutation_battery_sample_never_traces_back_or_hangs():
    from tests.battery import preload, run_battery

    cases = mutations.cases()[::6]
    preload(str(ROOT))
    results = run_battery(cases, str(ROOT), 120.0, jobs=2)
    bad = [f"{r.outcome} {r.case.name}: {r.stderr.strip()[-200:]}" for r in results
           if r.outcome in ("traceback", "multiline", "hang")]
    assert bad == []
