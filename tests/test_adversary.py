"""The adversarial battery (:mod:`tests.adversary`): unseen bad inputs across every verb and input kind.

``make test`` runs a few dozen of its cases, one statement of behaviour each
(special files, devices as outputs, misspelt safety keys, hostile payloads);
the slow suite runs all of them. Each CLI case runs in a forked child under
an address-space limit and a timeout and must end in exit 0 on a legal
input, or exit 2 with one line naming the input; never a traceback, a hang,
or a silent exit 0 on a bad input.
"""
from __future__ import annotations

import os
import shutil
import stat
import tempfile

import pytest

from tests import adversary, battery

#: make test: case name -> what it shows.
FAST = {
    "special/fifo/fit": "a FIFO given as a recording is refused at once, not waited on",
    "special/zero/diagnose-model": "/dev/zero given as a model file is refused before anything is read",
    "special/urandom/run-config": "/dev/urandom given as a run configuration is refused before anything is read",
    "special/sparse/compare": "a 64 GiB sparse recording is refused by its size, before it is read",
    "special/loop/simulate-plant": "a symlink loop is named in one line",
    "special/dangling/sweep-config": "a dangling symlink is a missing file",
    "special/newline/fit": "a file name with a line break in it still makes exactly one error line",
    "special/fifo/monitor-config": "a FIFO as the monitor's configuration does not block it",
    "args/fit -o dev null": "an output onto /dev/null is refused (renaming over it would replace the device)",
    "args/run --record fifo": "a run recording onto a FIFO is refused instead of blocking the run",
    "args/simulate -o /proc/x": "an output into /proc is refused before the simulation",
    "args/compare --json long name": "an output name longer than the file system takes is refused before the work",
    "args/fit -o trailing slash": "an output path ending in / names a folder, not a file",
    "args/simulate -o empty string": "an empty output path is refused",
    "args/monitor --duration inf": "the monitor refuses an infinite duration",
    "run.toml/loop.stale_msec_typo/run": "a misspelt watchdog key is an error, not silently the default",
    "run.toml/valve_node.command_timeout_typo/valve-node": "a misspelt valve-node timeout is an error",
    "run.toml/zenoh.key_typo/run": "a misspelt key id (ID = \"**\") is an error",
    "run.toml/ref_stale_ms_1e308/run": "a reference that never goes stale is refused",
    "run.toml/identify_stale_ms_1e308/identify": "identify's stale-measurement abort cannot be switched off",
    "run.toml/identify_flow_limit_1e308/identify": "identify's flow-limit abort cannot be switched off",
    "run.toml/alarms_supply_low_minus_1e308/run": "a supply alarm below vacuum is refused",
    "run.toml/node_aux_above_rate/valve-node": "the node's aux rate cannot exceed its step rate",
    "run.toml/model_dev_zero/run": "a run file naming /dev/zero as its model is refused",
    "run.toml/zenoh_config_dev_zero/valve-node": "a Zenoh configuration on /dev/zero is refused, not read for ever",
    "valves/pvp/plant.toml/model_fifo": "a valve's plant file naming a FIFO as its model is refused",
    "recording/one_row/run-reference-own-length": "a one-row reference without --duration is refused (no length)",
    "recording/time_gap_1e9_s_mid/run-reference-own-length": "a reference with a 1e9 s gap is refused",
    "recording/ref_1e308/run-reference": "a reference of 1e308 L/min is refused",
    "args/run --duration 1e308": "a run longer than its record can hold is refused",
    "args/run --inject model=1@0.1": "--inject takes plant settings and effect words only, not the model",
    "args/run --inject dead_zone=150@0.1": "an injected effect value outside its limits is refused before the run",
    "args/certs --host aaaaaaaaaaaaaaaaaaaa": "a 300-character host is no DNS name",
    "recording/cr_cr_lf/simulate-protocol": "legal: CR CR LF line ends are blank lines between rows",
    "run.toml/hex_rate_legal/run": "legal: a TOML hex integer is a rate",
}


@pytest.fixture(scope="module")
def prepared():
    # every verb's kernels compiled once in this process: each forked child inherits them. Left to the
    # children, a cold numba cache (a checkout whose kernels `make test` has not compiled) had each
    # `valvectl run` case compile the live loop's kernel itself, past its 30 s on a loaded machine
    battery.preload(adversary.ROOT)
    folder = tempfile.mkdtemp(prefix="adversary-")
    try:
        yield adversary.prepare(folder)
    finally:
        shutil.rmtree(folder, ignore_errors=True)


@pytest.fixture(scope="module")
def fast_results(prepared):
    models, special = prepared
    every = {c.name: c for c in adversary.cases(models, special)}
    missing = sorted(set(FAST) - set(every))
    assert not missing, f"fast cases not in the battery: {missing}"
    return {case.name: (outcome, r) for case, outcome, r in adversary.run_cases([every[n] for n in FAST], jobs=2)}


@pytest.mark.parametrize("name", list(FAST), ids=list(FAST))
def test_bad_input_ends_in_one_clear_line(fast_results, name):
    outcome, r = fast_results[name]
    assert outcome == "clean", f"{FAST[name]}: {outcome}, exit {r.rc}, {r.seconds:.1f} s\n{r.stderr[-6000:]}"


def test_device_targets_survive_their_cases(fast_results, prepared):
    _, special = prepared
    assert os.path.islink(special["devnull"]) and os.path.realpath(special["devnull"]) == "/dev/null"
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode)
    assert stat.S_ISFIFO(os.lstat(special["fifo_out"]).st_mode)


def test_every_payload_parser_and_the_monitor_view_are_total():
    """Hostile bytes on every key's parser and hostile statuses in the monitor's view: a value or a
    PayloadError, never an exception, a hang, a non-finite value or a status cell that breaks the CSV."""
    bad = [r for r in adversary.run_payloads() if r[1] != "clean"]
    assert not bad, "\n".join(f"{n}: {o} {d}" for n, o, d in bad)


@pytest.mark.slow
def test_the_whole_adversarial_battery_ends_cleanly(prepared):
    models, special = prepared
    results = adversary.run_cases(adversary.cases(models, special), jobs=2)
    bad = [(c.name, o, r.rc, (r.stderr.strip().splitlines() or [""])[-1][:200]) for c, o, r in results
           if o != "clean"]
    assert len(results) > 1000
    assert not bad, f"{len(bad)} of {len(results)} cases:\n" + "\n".join(map(str, bad))
