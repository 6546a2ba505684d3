"""Fuzzing the inputs: recordings, model files, TOML configurations and CLI arguments.

Every generated case runs the real CLI in-process (``controller.cli.main``)
and must end with exit 0, or exit 2 and exactly one line on stderr; never an
exception. Bounded example counts here; the ``slow`` tests run many more and
the whole hand-made battery (:mod:`tests.battery`) in forked children with a
timeout. The reader's properties are checked against an oracle: what Python's
own ``float`` makes of the cells that were written.
"""
from __future__ import annotations

import contextlib
import io
import json
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from controller.cli import main
from models.recording import InputError, read_recording
from tests import battery

ROOT = Path(__file__).resolve().parent.parent
FAST = settings(max_examples=10, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
SLOW = settings(max_examples=400, deadline=None, suppress_health_check=list(HealthCheck))


def cli(argv: list[str]) -> tuple[int, str]:
    """Exit code and stderr of one in-process CLI run (SystemExit from argparse included)."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = main(argv)
        except SystemExit as exc:
            code = exc.code
    return code, err.getvalue()


def assert_clean(code, err: str, argv) -> None:
    assert code in (0, 2), f"{argv}: exit {code}\n{err}"
    if code == 2:
        assert len(err.strip().splitlines()) == 1, f"{argv}: not one line:\n{err}"
        assert "Traceback" not in err


@contextlib.contextmanager
def folder(config: bool = False):
    d = tempfile.mkdtemp(prefix="fuzz-")
    try:
        if config:
            shutil.copytree(ROOT / "config", Path(d) / "config")
        yield Path(d)
    finally:
        shutil.rmtree(d, ignore_errors=True)


# -- recordings ------------------------------------------------------------------------------

NUMBERS = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**30, 10**30),
                    st.sampled_from([0.0, 50.0, 100.0, 1e308, -1e308, 1e-320]))
JUNK = st.sampled_from(["", " ", "abc", "nan", "inf", "-inf", "1e400", "1_0", "0x10", '"5"', "5 5", "é", "\t",
                        "1e-400", "--1", "+", "."])
CELL = st.one_of(NUMBERS.map(repr), JUNK)
COLUMNS = ["t_s", "duty_pct", "flow_lpm", "supply_bar", "ref_lpm", "coil_temp_c", "note", "t_s "]


@st.composite
def csv_texts(draw) -> bytes:
    """A CSV of random header, cells, line ends, BOM and blank lines (mostly bad, sometimes legal)."""
    header = draw(st.lists(st.sampled_from(COLUMNS), min_size=0, max_size=6))
    rows = draw(st.lists(st.lists(CELL, min_size=max(len(header) - 1, 0), max_size=len(header) + 1),
                         min_size=0, max_size=40))
    if draw(st.booleans()) and header:  # a plausible recording with one cell spoiled at most
        n = draw(st.integers(1, 60))
        t = np.cumsum(draw(st.sampled_from([0.01, 0.001, 1e-14, 1e9, 0.0, -0.01])) * np.ones(n))
        duty = draw(st.sampled_from([np.full(n, 50.0), 40 + 20 * np.sin(np.arange(n)), np.linspace(0, 101, n)]))
        cols = {"t_s": t, "duty_pct": duty, "flow_lpm": 2 * duty}
        rows = [[repr(float(cols[h][i])) if h in cols else "1" for h in header] for i in range(n)]
        if rows and draw(st.booleans()):
            rows[draw(st.integers(0, n - 1))][draw(st.integers(0, len(header) - 1))] = draw(CELL)
    eol = draw(st.sampled_from(["\n", "\r\n", "\r"]))
    lines = [",".join(header)] + [",".join(r) for r in rows]
    if draw(st.booleans()) and len(lines) > 2:
        lines.insert(draw(st.integers(1, len(lines) - 1)), draw(st.sampled_from(["", "  "])))
    text = eol.join(lines) + draw(st.sampled_from(["", eol]))
    return (b"\xef\xbb\xbf" if draw(st.booleans()) else b"") + text.encode("utf-8")


def _recording_case(data: bytes, verb: str) -> None:
    with folder() as d:
        (d / "rec.csv").write_bytes(data)
        argv = {"fit": ["fit", str(d / "rec.csv"), "--model", "pi", "--n", "5", "-o", str(d / "m.json")],
                "simulate": ["simulate", "--protocol", str(d / "rec.csv"), "--rate", "50", "-o", str(d / "s.csv")],
                }[verb]
        assert_clean(*cli(argv), argv)


@FAST
@given(csv_texts())
def test_fuzz_recordings_through_fit(data):
    _recording_case(data, "fit")


@FAST
@given(csv_texts())
def test_fuzz_recordings_as_protocol_files(data):
    _recording_case(data, "simulate")


@pytest.mark.slow
@SLOW
@given(csv_texts(), st.sampled_from(["fit", "simulate"]))
def test_fuzz_recordings_long(data, verb):
    _recording_case(data, verb)


FINITE = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)


@FAST
@given(st.lists(st.tuples(st.floats(0, 100), FINITE), min_size=2, max_size=50),
       st.sampled_from(["\n", "\r\n"]), st.booleans(), st.lists(st.integers(0, 60), max_size=3),
       st.sampled_from(["{!r}", " {!r} ", "{:.17g}"]))
def test_reader_returns_exactly_what_was_written(tmp_path_factory, rows, eol, bom, blanks, fmt):
    """Any formatting the format allows (BOM, CRLF, blank lines, spaces) reads back to the written floats."""
    lines = ["t_s, duty_pct ,flow_lpm,note"] + [",".join([fmt.format(0.5 * i), fmt.format(d), fmt.format(f), "x y"])
                                               for i, (d, f) in enumerate(rows)]
    for b in sorted(blanks, reverse=True):
        lines.insert(min(b, len(lines) - 1) + 1, "")
    p = tmp_path_factory.mktemp("rec") / "r.csv"
    p.write_bytes((b"\xef\xbb\xbf" if bom else b"") + eol.join(lines).encode())
    rec = read_recording(p)
    np.testing.assert_array_equal(rec.duty_pct, [float(fmt.format(d)) for d, _ in rows])
    np.testing.assert_array_equal(rec.flow_lpm, [float(fmt.format(f)) for _, f in rows])
    assert rec.text_columns["note"] == ["x y"] * len(rows)


@FAST
@given(st.integers(3, 400), st.data())
def test_first_bad_row_is_named_by_its_line(tmp_path_factory, n, data):
    """One spoiled cell (not a number, not finite, duty out of range, time backwards) is reported at its line,
    counting the header and any blank lines before it."""
    t = np.arange(n) * 0.01
    cells = [[repr(float(a)), "50.0", "1.0"] for a in t]
    row = data.draw(st.integers(1, n - 1))
    kind, col, value = data.draw(st.sampled_from([("not a number", 2, "abc"), ("finite", 1, "nan"),
                                                   ("outside", 1, "100.5"), ("does not increase", 0, "-1")]))
    cells[row][col] = value
    lines = ["t_s,duty_pct,flow_lpm"] + [",".join(c) for c in cells]
    blanks = data.draw(st.integers(0, 3))
    at = data.draw(st.integers(1, row + 1))
    lines[at:at] = [""] * blanks  # blank lines before the bad row move it down
    p = tmp_path_factory.mktemp("rec") / "r.csv"
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError) as err:
        read_recording(p)
    assert str(err.value).startswith(f"{p}:{row + 2 + blanks}:") and kind in str(err.value)


# -- model files -----------------------------------------------------------------------------

JSON_VALUES = st.one_of(st.floats(), st.integers(-10**400, 10**400), st.text(max_size=5), st.none(), st.booleans(),
                        st.lists(st.floats(), max_size=4), st.dictionaries(st.text(max_size=3), st.floats(), max_size=2))


def _paths(obj, prefix=()):
    yield prefix
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _paths(v, prefix + (i,))


@st.composite
def model_texts(draw) -> str:
    """A valid model file of a random kind with one value replaced, or nested deep, or cut short."""
    m = draw(st.sampled_from(list(battery._kind_models().values())))
    m = json.loads(json.dumps(m))
    paths = [p for p in _paths(m) if p]
    path = draw(st.sampled_from(paths))
    how = draw(st.sampled_from(["replace", "delete", "nest", "truncate"]))
    node = m
    for k in path[:-1]:
        node = node[k]
    if how == "replace":
        node[path[-1]] = draw(JSON_VALUES)
    elif how == "delete":
        del node[path[-1]]
    elif how == "nest":  # spliced in as text: json.dumps itself recurses, and hypothesis's stack is deep already
        node[path[-1]] = "\x00deep\x00"
    text = json.dumps(m)
    if how == "nest":
        n = draw(st.integers(1, 3000))
        text = text.replace('"\\u0000deep\\u0000"', "[" * n + "1.0" + "]" * n)
    if how == "truncate":
        text = text[: draw(st.integers(0, len(text)))]
    return text


def _model_case(text: str) -> None:
    with folder(config=True) as d:
        (d / "config" / "valve_model.json").write_text(text)
        argv = ["simulate", "--plant", str(d / "config" / "plant.toml"), "--duration", "0.5", "--rate", "100",
                "-o", str(d / "s.csv")]
        assert_clean(*cli(argv), argv)


@FAST
@given(model_texts())
def test_fuzz_model_files(text):
    _model_case(text)


@pytest.mark.slow
@SLOW
@given(model_texts())
def test_fuzz_model_files_long(text):
    _model_case(text)


# -- TOML configurations ---------------------------------------------------------------------

TOML_VALUES = st.sampled_from(["0", "-1", "nan", "inf", "-inf", "1e308", "1e-300", '"x"', '""', '"**"', "true",
                               "[]", "[1, 2]", "{a = 1}", "3", "0.5", "100.0", "150", "99999999999999999999",
                               '"a/b"', '"$*"'])


def _toml_keys(text: str) -> list[int]:
    return [i for i, line in enumerate(text.splitlines()) if "=" in line and not line.lstrip().startswith("#")]


@st.composite
def edited_tomls(draw, name: str) -> str:
    """``config/NAME`` with one to three values replaced by odd TOML values."""
    lines = (ROOT / "config" / name).read_text().splitlines()
    for i in draw(st.lists(st.sampled_from(_toml_keys("\n".join(lines))), min_size=1, max_size=3)):
        key = lines[i].split("=")[0]
        lines[i] = f"{key}= {draw(TOML_VALUES)}"
    return "\n".join(lines) + "\n"


def _run_toml_case(text: str) -> None:
    with folder(config=True) as d:
        (d / "config" / "run.toml").write_text(text)
        argv = ["run", "--config", str(d / "config" / "run.toml"), "--duration", "0.05"]
        assert_clean(*cli(argv), argv)


def _plant_toml_case(text: str) -> None:
    with folder(config=True) as d:
        (d / "config" / "plant.toml").write_text(text)
        argv = ["simulate", "--plant", str(d / "config" / "plant.toml"), "--duration", "0.5", "-o", str(d / "s.csv")]
        assert_clean(*cli(argv), argv)


@FAST
@given(edited_tomls("run.toml"))
def test_fuzz_run_toml(text):
    _run_toml_case(text)


@FAST
@given(edited_tomls("plant.toml"))
def test_fuzz_plant_toml(text):
    _plant_toml_case(text)


@pytest.mark.slow
@SLOW
@given(edited_tomls("run.toml"))
def test_fuzz_run_toml_long(text):
    _run_toml_case(text)


@pytest.mark.slow
@SLOW
@given(edited_tomls("plant.toml"))
def test_fuzz_plant_toml_long(text):
    _plant_toml_case(text)


# -- CLI arguments ---------------------------------------------------------------------------

ARG_NUMBERS = st.sampled_from(["nan", "-nan", "inf", "-inf", "-1", "0", "1e308", "1e-308", "x", "", "1e999",
                               "99999999999999999999999", "0x10", "1", "0.05"])


@st.composite
def argvs(draw, d: Path) -> list[str]:
    """A command line of fit, simulate or run with odd numbers and paths (run always short or refused)."""
    rec = str(d / "rec.csv")
    path = st.sampled_from([str(d / "out.x"), str(d / "no" / "out.x"), str(d), "", str(d / "rec.csv")])
    verb = draw(st.sampled_from(["fit", "simulate", "run"]))
    if verb == "fit":
        return ["fit", rec, "--model", draw(st.sampled_from(["pi", "pi-asym", "warp", "pi-mod"])), "--n",
                draw(ARG_NUMBERS), "-o", draw(path)]
    if verb == "simulate":
        return ["simulate", "--duration", draw(ARG_NUMBERS), "--rate", draw(ARG_NUMBERS), "--seed",
                draw(st.sampled_from(["-1", "0", "1e3", "99999999999999999999999"])), "-o", draw(path)]
    duration = draw(st.sampled_from(["nan", "-1", "inf", "-inf", "x", "0.05", "1e-9"]))
    return ["run", "--config", str(ROOT / "config" / "run.toml"), "--duration", duration, "--json", draw(path)]


@FAST
@given(st.data())
def test_fuzz_cli_arguments(data):
    with folder() as d:
        (d / "rec.csv").write_text(battery._recording(n=200))
        argv = data.draw(argvs(d))
        assert_clean(*cli(argv), argv)


# -- the hand-made battery -------------------------------------------------------------------

def _battery(selected, timeout_s: float) -> list:
    results = battery.run_battery(selected, str(ROOT), timeout_s, jobs=2)
    return [f"{r.outcome} rc={r.rc} {r.case.name}: {r.stderr.strip()[-300:]}" for r in results
            if r.outcome != "clean"]


def test_battery_sample_ends_cleanly():
    """Every 60th hand-made bad input, in a forked child with a timeout: exit 2 with one line (or 0 if legal)."""
    cases = battery.cases()[::60]
    assert _battery(cases, timeout_s=120) == []


@pytest.mark.slow
def test_battery_ends_cleanly():
    """All of the battery: no traceback, no hang, no silent acceptance, one line each."""
    battery.preload(str(ROOT))
    assert _battery(battery.cases(), timeout_s=120) == []


def test_battery_counts_inputs_of_every_kind():
    """The battery covers every verb and input kind with several hundred bad inputs."""
    cases = battery.cases()
    assert sum(not c.legal for c in cases) > 500
    kinds = {c.name.split("/")[0] for c in cases}
    assert kinds >= {"recording", "model", "run.toml", "plant.toml", "sweep.toml", "args"}
    verbs = {c.argv[0] for c in cases if c.argv}
    assert verbs >= {"fit", "compare", "simulate", "run", "valve-node", "sweep", "diagnose"}
    assert len({c.name for c in cases}) == len(cases)


def test_a_model_file_leaving_out_a_field_with_a_default_loads_with_the_default(tmp_path):
    """The schema's defaults reach the model (hypothesis found an inverse without ``offset``: a KeyError)."""
    from models.model import load_model

    d = json.loads((Path(__file__).parents[1] / "config" / "valve_model.json").read_text())
    del d["params"]["offset"], d["inverse"]["params"]["offset"]
    (tmp_path / "m.json").write_text(json.dumps(d))
    m = load_model(tmp_path / "m.json")
    assert m.core.offset == 0.0 and m.inverse.offset == 0.0
