"""An adversarial battery of unseen bad inputs, written the way an outside judge would write one.

:mod:`tests.battery`, :mod:`tests.mutations` and :mod:`tests.test_fuzz`
break the shipped files and a few shapes of CSV. This battery goes where
they do not:

- **special files** where a file is read: a FIFO with no writer, ``/dev/zero``
  and ``/dev/urandom`` (endless), a 64 GiB sparse file, a symlink loop, a
  dangling symlink, a directory, ``/proc`` text; a file name with a newline
  in it (an error line must stay one line);
- **recordings** through every verb that reads one (``fit`` of every kind,
  ``compare``, ``diagnose``, ``simulate --protocol FILE``, ``run --reference
  FILE``): quoted cells, whitespace, trailing commas, comment lines, a
  second header, upper-case names, decimal commas, UTF-16, a zero-width
  space, ``-0``, subnormals, values on each range bound and just past it, a
  reference of one row or with a 1e9 s gap (the run's length comes from it);
- **model files of every kind**, including ``pi-mod`` (the real valve's),
  built by ``fit`` and then spoiled field by field: numbers as strings and
  booleans, arrays nested or 200 000 long, thresholds unsorted, the
  dead-zone thresholds without their zero, inverse and forward disagreeing;
- **TOML**: the run file's safety keys misspelt (an unknown key must be an
  error: a typo there would switch the safety off silently), TOML's own
  forms (dotted keys, inline tables, arrays of tables, dates, hex), the
  cross-field rules, paths pointing at special files, the valves'
  ``config/valves/*`` files, sweep specs (a candidate range that leaves the
  run file's schema, a spec that names itself as its run file);
- **CLI arguments**: ``--inject`` and ``--effect`` in every malformed shape and
  on every bound, output paths into ``/proc``, onto ``/dev/full``, with a
  255+ character name, through a dangling symlink; durations that are legal
  but long (a run of 10^6 s must not allocate its whole record up front);
  ``--workers`` and ``--scheduler`` of a sweep; ``certs`` options;
- **Zenoh payloads** in-process: the parsers of :mod:`controller.transport.payload`
  and the monitor's status view (:mod:`controller.monitor`) fed hostile bytes.

Every CLI case runs in a forked child (:func:`tests.battery.run_battery`)
under an address-space limit, with a timeout, and must end in exit 0 (legal
input) or exit 2 with exactly one line on stderr that names the input
(``expect``: a word the line must hold, e.g. the file or the key). Outcomes:
``clean``, ``accepted`` (exit 0 on a bad input), ``multiline``, ``vague``
(one line, but it does not name the input), ``traceback``, ``hang``.

``python -m tests.adversary [--jobs N] [-k WORD] [--json OUT] [-v]`` prints the
counts by group and every case that did not end cleanly.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import re
import resource
import signal
import sys
import tempfile
import time
from dataclasses import dataclass

import numpy as np

from tests.battery import Case, preload, run_battery

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OUTCOMES = ("clean", "accepted", "multiline", "vague", "traceback", "hang")
#: Address space of each child: a verb that tries to allocate without bound fails here, not in the host.
MEMORY_LIMIT = 6 << 30
KINDS = ("pi", "pi-asym", "pi-mod", "preisach", "preisach-cont", "bouc-wen")


@dataclass
class XCase(Case):
    """A :class:`tests.battery.Case` with what its error line must name and how long it may take.

    ``legal``: True (exit 0 expected), False (exit 2 expected), None (either is right).
    ``expect``: a substring the one error line must contain (the file, the flag or the key).
    ``timeout``: seconds before the case counts as a hang. ``long_ok``: still running at the
    timeout is right (a legal run of a long duration), as long as it did not die.
    """

    expect: str = ""
    timeout: float = 30.0
    long_ok: bool = False


def judge(case: XCase, rc, stderr: str) -> str:
    if rc is None:
        return "clean" if case.long_ok else "hang"
    if "Traceback (most recent call last)" in stderr or rc not in (0, 2):
        return "traceback"
    if rc == 0:
        return "accepted" if case.legal is False else "clean"
    lines = stderr.strip().splitlines()
    if len(lines) != 1:
        return "multiline"
    if case.legal is True:
        return "clean" if case.expect.lower() in lines[0].lower() else "vague"  # a legal input refused: see expect
    return "clean" if case.expect.lower() in lines[0].lower() else "vague"


# -- the inputs --------------------------------------------------------------------------------

def base_recording(n: int = 2000, rate_hz: float = 100.0) -> dict[str, np.ndarray]:
    """A valve-like recording: duty triangles of shrinking amplitude through two play operators."""
    t = np.arange(n) / rate_hz
    phase = (t * 0.4) % 1.0
    tri = 1 - 2 * np.abs(phase - 0.5) * 2 + 0.0
    duty = 55.0 + (20.0 - 8.0 * t / t[-1]) * np.clip(tri, -1, 1)
    ys = []
    for r in (1.0, 4.0):
        s, y = duty[0], np.empty(n)
        for i, x in enumerate(duty):
            s = min(max(s, x - r), x + r)
            y[i] = s
        ys.append(y)
    flow = np.maximum(0.0, 3.0 * (0.6 * ys[0] + 0.4 * ys[1] - 38.0))
    ref = np.where((t % 3.0) < 1.0, 60.0, 5.0)
    return {"t_s": t, "duty_pct": duty, "flow_lpm": flow, "ref_lpm": ref}


def csv_text(cols: dict, names=None, eol="\n", fmt="{:.6g}") -> str:
    names = list(cols) if names is None else names
    rows = [",".join(names)]
    for i in range(len(next(iter(cols.values())))):
        rows.append(",".join(fmt.format(cols[k][i]) if not isinstance(cols[k][i], str) else cols[k][i] for k in names))
    return eol.join(rows) + eol


#: verb class -> the columns it needs (rec: fit, compare, diagnose; proto: simulate --protocol; ref: run --reference)
NEEDS = {"rec": {"t_s", "duty_pct", "flow_lpm", "ref_lpm"}, "proto": {"t_s", "duty_pct"}, "ref": {"t_s", "ref_lpm"}}


def recordings() -> list[tuple[str, str | bytes, set, str]]:
    """(name, content, the verb classes it is legal for, word the error must name)."""
    c = base_recording()
    good = csv_text(c)
    head, *body = good.splitlines()
    out: list[tuple[str, str | bytes, set, str]] = []
    ALL, NONE = {"rec", "proto", "ref"}, set()

    def add(name, content, legal=NONE, expect="rec.csv"):
        out.append((name, content, set(legal), expect))

    def cell(col: str, row: int, value: str) -> str:
        j = head.split(",").index(col)
        lines = list(body)
        cells = lines[row].split(",")
        cells[j] = value
        lines[row] = ",".join(cells)
        return "\n".join([head, *lines]) + "\n"

    def spoils(col):  # legal for the verb classes that do not read ``col``
        return {k for k, need in NEEDS.items() if col not in need}

    add("good", good, ALL)
    add("quoted_cells", "\n".join([head] + [",".join(f'"{x}"' for x in b.split(",")) for b in body]) + "\n")
    add("quoted_header", '"t_s","duty_pct","flow_lpm","ref_lpm"\n' + "\n".join(body) + "\n")
    add("spaces_around_cells", "\n".join([head] + [" , ".join(b.split(",")) for b in body]) + "\n", ALL)
    add("trailing_comma", "\n".join([head + ","] + [b + "," for b in body]) + "\n", ALL)  # an empty, unnamed column
    add("leading_comma", "\n".join(["," + head] + ["," + b for b in body]) + "\n", ALL)
    add("comment_line", "# exported by bench\n" + good)
    add("comment_mid", "\n".join([head, *body[:50], "# pause", *body[50:]]) + "\n")
    add("second_header", "\n".join([head, *body[:300], head, *body[300:]]) + "\n")
    add("upper_case_header", good.replace("t_s,duty_pct", "T_S,DUTY_PCT", 1))
    add("header_spaces_inside", good.replace("duty_pct", "duty pct", 1), {"ref"})
    add("decimal_comma_semicolon", "\n".join([head.replace(",", ";")] + [b.replace(",", ";").replace(".", ",")
                                                                         for b in body]) + "\n")
    add("tab_and_comma_mixed", "\n".join([head] + [b.replace(",", "\t", 1) if i % 7 == 3 else b
                                                   for i, b in enumerate(body)]) + "\n")
    add("utf16_bom", "\ufeff".encode("utf-16-le") + good.encode("utf-16-le"), NONE)
    add("utf8_bom_twice", "\ufeff\ufeff" + good)
    add("zero_width_space", cell("flow_lpm", 30, "1\u200b2"), spoils("flow_lpm"))
    add("nbsp_in_cell", cell("duty_pct", 30, "50\u00a0"), ALL)
    add("fullwidth_digits_time", cell("t_s", 5, "０.05"))
    add("minus_zero_everywhere", good.replace(",0,", ",-0,"), ALL)
    add("minus_zero_time_start", cell("t_s", 0, "-0"), ALL)
    add("negative_time_start", csv_text({**c, "t_s": c["t_s"] - 1000.0}), ALL)
    add("subnormal_duty", cell("duty_pct", 10, "4.9e-324"), ALL)
    add("duty_exactly_0_and_100", cell("duty_pct", 10, "0") .replace("\n" + body[11], "\n" + ",".join(
        [body[11].split(",")[0], "100", *body[11].split(",")[2:]]), 1), ALL)
    add("duty_100_plus_ulp", cell("duty_pct", 10, "100.00000000000001"), spoils("duty_pct"))
    add("duty_minus_tiny", cell("duty_pct", 10, "-1e-300"), spoils("duty_pct"))
    add("duty_percent_sign", cell("duty_pct", 10, "50%"), spoils("duty_pct"))
    add("flow_1e6_bound", cell("flow_lpm", 10, "1e6"), ALL)  # a spike within RANGES: legal data
    add("flow_past_bound", cell("flow_lpm", 10, "1.0000001e6"), spoils("flow_lpm"))
    add("ref_1e308", cell("ref_lpm", 10, "1e308"), {"proto"})
    add("ref_minus_1e308", cell("ref_lpm", 10, "-1e308"), {"proto"})
    add("ref_nan", cell("ref_lpm", 10, "nan"), {"proto"})
    add("ref_empty", cell("ref_lpm", 10, ""), {"proto"})
    add("supply_column_inf", csv_text({**c, "supply_bar": np.where(np.arange(len(c["t_s"])) == 40, np.inf, 3.0)}),
        {"proto", "ref"})
    add("coil_temp_below_absolute_zero", csv_text({**c, "coil_temp_c": np.full(len(c["t_s"]), -300.0)}),
        {"proto", "ref"})
    add("time_duplicate_first", cell("t_s", 1, body[0].split(",")[0]))
    add("time_backwards_last", cell("t_s", len(body) - 1, "0.5"))
    add("time_all_equal", csv_text({**c, "t_s": np.zeros(len(c["t_s"]))}))
    add("time_gap_1e6_s_at_end", cell("t_s", len(body) - 1, "1e6"), {"proto"})
    add("time_gap_1e9_s_mid", csv_text({**c, "t_s": np.where(np.arange(len(c["t_s"])) < 400, c["t_s"],
                                                              c["t_s"] + 1e9)}), NONE)
    add("time_1e14_hz", csv_text({**c, "t_s": np.arange(len(c["t_s"])) * 1e-14}, fmt="{:.17g}"), {"proto"})
    add("time_1e-4_hz", csv_text({**c, "t_s": np.arange(len(c["t_s"])) * 1e4}), {"proto"})
    add("time_jitter_unsorted_pair", cell("t_s", 200, body[202].split(",")[0]))
    add("one_row", "\n".join([head, body[0]]) + "\n", {"proto", "ref"})
    add("two_rows_same_duty", "\n".join([head, body[0], body[0].replace(body[0].split(",")[0], "0.01", 1)]) + "\n",
        {"proto", "ref"})
    add("nineteen_rows", "\n".join([head, *body[:19]]) + "\n", {"proto", "ref"})
    add("constant_flow", csv_text({**c, "flow_lpm": np.full(len(c["t_s"]), 42.0)}), {"proto", "ref"})
    add("header_only_crlf", head + "\r\n")
    add("bom_newline_only", "\ufeff\n")
    add("only_commas", ",,,\n,,,\n")
    add("header_empty_name", head + ",\n" + "\n".join(b + ",x" for b in body) + "\n", ALL)
    add("header_10000_columns", head + "," + ",".join(f"x{i}" for i in range(10000)) + "\n"
        + "\n".join(b + "," + ",".join(["0"] * 10000) for b in body[:100]) + "\n", ALL)
    add("line_1MB", "\n".join([head, *body[:10], body[10] + "," + "1" * (1 << 20), *body[11:]]) + "\n")
    add("gzip_bytes", b"\x1f\x8b\x08\x00" + bytes(range(200)) * 20)
    add("png_bytes", b"\x89PNG\r\n\x1a\n" + bytes(256) + b"IEND")
    add("nul_in_header", "t_s\x00,duty_pct,flow_lpm,ref_lpm\n" + "\n".join(body) + "\n")
    add("latin1_in_extra_column", (head + ",note\n" + "\n".join(b + ",ok" for b in body[:-1])).encode()
        + ("\n" + body[-1] + ",caf\xe9\n").encode("latin-1"))
    add("crlf_mixed_lf", "\r\n".join([head, *body[:300]]) + "\n" + "\n".join(body[300:]) + "\n", ALL)
    add("cr_cr_lf", good.replace("\n", "\r\r\n"), ALL)
    add("nan_as_word_null", cell("flow_lpm", 12, "null"), spoils("flow_lpm"))
    add("int_400_digits_flow", cell("flow_lpm", 12, "9" * 400), spoils("flow_lpm"))
    add("exponent_huge", cell("duty_pct", 12, "1e99999"), spoils("duty_pct"))
    add("plus_sign_numbers", good.replace(",5", ",+5"), ALL)
    add("duplicate_t_s_column", "\n".join([head + ",t_s"] + [b + "," + b.split(",")[0] for b in body]) + "\n")
    add("missing_flow_column", csv_text({k: v for k, v in c.items() if k != "flow_lpm"}), {"proto", "ref"})
    add("missing_duty_column", csv_text({k: v for k, v in c.items() if k != "duty_pct"}), {"ref"})
    add("extra_numeric_and_text_columns", csv_text({**c, "supply_bar": np.full(len(c["t_s"]), 3.0),
                                                   "coil_temp_c": np.full(len(c["t_s"]), 30.0)}).replace(
        "\n", ",x\n").replace("coil_temp_c,x", "coil_temp_c,note", 1), ALL)
    add("columns_reordered", csv_text(c, names=["flow_lpm", "ref_lpm", "t_s", "duty_pct"]), ALL)
    return out


def _fit_models(folder: str, rec: str) -> dict[str, dict]:
    """One fitted model file of every kind (the battery's valid bases), fitted in this process."""
    import contextlib
    import io

    from controller.cli import main

    out = {}
    for kind in KINDS:
        path = os.path.join(folder, f"{kind}.json")
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            n = [] if kind == "bouc-wen" else ["--n", "8" if kind.startswith("pi") else "5"]
            main(["fit", rec, "--model", kind, *n, "-o", path])
        with open(path) as fh:
            out[kind] = json.load(fh)
    return out


def _walk_numbers(node, path=()):
    """(path, value) of every number in a JSON document."""
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _walk_numbers(v, path + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _walk_numbers(v, path + (i,))
    elif isinstance(node, (int, float)) and not isinstance(node, bool):
        yield path, node


def _set(doc, path, value):
    d = json.loads(json.dumps(doc))
    node = d
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = value
    return d


def _del(doc, path):
    d = json.loads(json.dumps(doc))
    node = d
    for k in path[:-1]:
        node = node[k]
    del node[path[-1]]
    return d


def model_mutations(models: dict[str, dict]) -> list[tuple[str, str, bool | None, str]]:
    """(name, JSON text, legal, word the error must name) per kind."""
    out = []
    for kind, m in models.items():
        def add(name, doc, legal=False, expect="m.json"):
            out.append((f"{kind}/{name}", doc if isinstance(doc, (str, bytes)) else json.dumps(doc), legal, expect))

        add("as_fitted", m, True)
        params = m["params"]
        arrays = [k for k, v in params.items() if isinstance(v, list)]
        scalars = [k for k, v in params.items() if isinstance(v, (int, float)) and not isinstance(v, bool)]
        for k in arrays[:3]:
            first = params[k][0]
            idx = (k, 0, 0) if isinstance(first, list) else (k, 0)
            add(f"{k}_number_as_string", _set(m, ("params",) + idx, str(first if not isinstance(first, list)
                                                                         else first[0])), expect=k)
            add(f"{k}_true", _set(m, ("params",) + idx, True), expect=k)
            add(f"{k}_nested", _set(m, ("params",) + idx, [[0.5]]), expect=k)
            add(f"{k}_200000_long", _set(m, ("params", k), [0.0] * 200_000), expect=k)
            add(f"{k}_as_object", _set(m, ("params", k), {"0": 0.5}), expect=k)
            add(f"{k}_reversed", _set(m, ("params", k), params[k][::-1]),
                None if kind in ("preisach-cont",) else None)  # thresholds: must refuse (see below)
        for k in scalars[:3]:
            add(f"{k}_as_string", _set(m, ("params", k), str(params[k])), expect=k)
            add(f"{k}_false", _set(m, ("params", k), False), expect=k)
            add(f"{k}_1e300", _set(m, ("params", k), 1e300), expect=k)
        for key in ("format", "version", "kind", "input", "output", "params"):
            add(f"missing_{key}", _del(m, (key,)), expect=key)
        add("extra_top_key", {**m, "paramz": {}}, expect="paramz")
        add("extra_scale_key", _set(m, ("input", "unit"), "%"), expect="unit")
        add("kind_upper_case", {**m, "kind": kind.upper()}, expect="kind")
        add("version_as_string", {**m, "version": "1"}, expect="version")
        add("half_range_1e-300", _set(m, ("input", "half_range"), 1e-300), None)
        add("half_range_true", _set(m, ("output", "half_range"), True), expect="half_range")
        add("center_string", _set(m, ("output", "center"), "100"), expect="center")
        add("nan_literal_in_params", json.dumps(m).replace(json.dumps(params[arrays[0]][0] if arrays
                                                                      else params[scalars[0]]), "NaN", 1))
        add("trailing_garbage", json.dumps(m) + " x")
        add("two_documents", json.dumps(m) + json.dumps(m))
        add("json5_comment", "// model\n" + json.dumps(m))
        add("meta_deep_but_legal", {**m, "meta": {"a": {"b": {"c": [1, [2, [3]]]}}}}, True)
        add("deep_1000", json.dumps(m)[:-1] + ', "deep": ' + "[" * 1000 + "]" * 1000 + "}")
        add("utf16", ("\ufeff" + json.dumps(m)).encode("utf-16-le"))
    # kind-specific rules
    pi = models["pi"]
    n = 25_000  # MAX_ELEMENTS operators: legal, and every verb must finish with them
    big = _set(_set(_set(pi, ("params", "r"), [i / n for i in range(n)]), ("params", "w"), [1.0 / n] * n),
               ("params", "y0"), None)
    out.append(("pi/25000_operators_legal", json.dumps(_del(big, ("inverse",))), None, "m.json"))
    out.append(("pi/r_unsorted", json.dumps(_set(pi, ("params", "r"), [pi["params"]["r"][1], pi["params"]["r"][0],
                                                                     *pi["params"]["r"][2:]])), False, "r"))
    out.append(("pi/inverse_missing_for_ff", json.dumps(_del(pi, ("inverse",))), None, "inverse"))
    out.append(("pi/inverse_w_mismatch", json.dumps(_set(pi, ("inverse", "params", "w"), [1.0])), False, "w"))
    pm = models["pi-mod"]
    h = pm["params"]["h"]
    out.append(("pi-mod/h_without_zero", json.dumps(_set(pm, ("params", "h"), [x + 0.5 if x == 0 else x for x in h])),
                False, "h"))
    out.append(("pi-mod/h_two_zeros", json.dumps(_set(pm, ("params", "h"), sorted([0.0] + h))), False, "h"))
    out.append(("pi-mod/floor_nan", json.dumps(pm).replace('"floor": ', '"floor": NaN, "x_": ', 1)
                if '"floor"' in json.dumps(pm) else json.dumps(_set(pm, ("params", "floor"), "nan")), False, "floor"))
    out.append(("pi-mod/floor_above_range", json.dumps(_set(pm, ("params", "floor"), 1e9)), None, "floor"))
    out.append(("pi-mod/g_all_zero", json.dumps(_set(pm, ("params", "g"), [0.0] * len(pm["params"]["g"]))),
                None, "g"))
    out.append(("pi-mod/inverse_forward_differs", json.dumps(_set(pm, ("inverse", "params", "forward", "offset"),
                                                                   pm["params"].get("offset", 0.0) + 0.5)), None,
                "inverse"))
    out.append(("pi-mod/w_negative_first", json.dumps(_set(pm, ("params", "w", 0), -abs(pm["params"]["w"][0]))),
                None, "w"))
    pa = models["pi-asym"]
    out.append(("pi-asym/p_zero", json.dumps(_set(pa, ("params", "p"), 0.0)), False, "p"))
    out.append(("pi-asym/a_negative", json.dumps(_set(pa, ("params", "a"), -0.1)), False, "a"))
    pr = models["preisach"]
    out.append(("preisach/alpha_below_beta", json.dumps(_set(pr, ("params", "alpha", 0), pr["params"]["beta"][0] - 1)),
                False, "alpha"))
    out.append(("preisach/mu_shorter", json.dumps(_set(pr, ("params", "mu"), pr["params"]["mu"][:-1])), False, "mu"))
    pc = models["preisach-cont"]
    ev = pc["params"]["everett"]
    out.append(("preisach-cont/not_square", json.dumps(_set(pc, ("params", "everett"), [r[:-1] for r in ev])),
                False, "everett"))
    out.append(("preisach-cont/one_row", json.dumps(_set(pc, ("params", "everett"), [[0.0]])), False, "everett"))
    bw = models["bouc-wen"]
    out.append(("bouc-wen/beta_below_gamma", json.dumps(_set(_set(bw, ("params", "beta"), 0.1), ("params", "gamma"),
                                                             0.5)), False, "beta"))
    out.append(("bouc-wen/n_zero", json.dumps(_set(bw, ("params", "n"), 0.0)), False, "n"))
    out.append(("bouc-wen/n_1e308", json.dumps(_set(bw, ("params", "n"), 1e308)), False, "n"))
    return out


RUN_TOML_EDITS = [
    # (name, find, replace, legal, expect): misspelt safety keys first
    ("loop.stale_msec_typo", "stale_ms = 50.0", "stale_msec = 5000.0", False, "stale_msec"),
    ("loop.safe_duty_typo", "safe_duty_pct = 0.0", "safe_duty = 50.0", False, "safe_duty"),
    ("valve_node.command_timeout_typo", "command_timeout_ms = 100.0", "command_timeout = 1e9", False,
     "command_timeout"),
    ("limits.duty_max_typo", "duty_max_pct = 100.0", "duty_max = 150.0", False, "duty_max"),
    ("zenoh.key_typo", 'id = "insp"', 'ID = "**"', False, "ID"),
    ("section_typo_loop", "[loop]", "[Loop]", False, "Loop"),
    ("top_level_dotted_rate_0", "seed = 0 ", "loop.rate_hz = 0\nseed = 0 ", False, "run.toml"),
    ("inline_table_loop", "[loop]\nrate_hz = 1000.0", "[loopx]\nrate_hz = 1000.0", False, "loopx"),
    ("array_of_tables_limits", "[limits]", "[[limits]]", False, "limits"),
    ("duplicate_key", "stale_ms = 50.0", "stale_ms = 50.0\nstale_ms = 60.0", False, "run.toml"),
    ("date_as_rate", "rate_hz = 1000.0", "rate_hz = 1979-05-27T07:32:00Z", False, "rate_hz"),
    ("time_as_stale", "stale_ms = 50.0", "stale_ms = 07:32:00", False, "stale_ms"),
    ("hex_rate_legal", "rate_hz = 1000.0", "rate_hz = 0x3E8", True, ""),
    ("underscore_rate_legal", "rate_hz = 1000.0", "rate_hz = 1_000", True, ""),
    ("int_2_64_rate", "rate_hz = 1000.0", "rate_hz = 18446744073709551616", False, "rate_hz"),
    ("stale_ms_subnormal", "stale_ms = 50.0", "stale_ms = 5e-324", None, "stale_ms"),
    ("stale_ms_10001", "stale_ms = 50.0", "stale_ms = 10001.0", False, "stale_ms"),
    ("stale_ms_string", "stale_ms = 50.0", 'stale_ms = "50"', False, "stale_ms"),
    ("stale_ms_array", "stale_ms = 50.0", "stale_ms = [50.0]", False, "stale_ms"),
    ("ref_stale_ms_1e308", "ref_stale_ms = 500.0", "ref_stale_ms = 1e308", False, "ref_stale_ms"),
    ("ref_stale_ms_inf", "ref_stale_ms = 500.0", "ref_stale_ms = inf", False, "ref_stale_ms"),
    ("safe_duty_100_legal", "safe_duty_pct = 0.0", "safe_duty_pct = 100.0", True, ""),
    ("safe_duty_below_min", "safe_duty_pct = 0.0", "safe_duty_pct = 0.0", True, ""),
    ("duty_min_eq_max", "duty_min_pct = 0.0", "duty_min_pct = 100.0", False, "duty_min_pct"),
    ("duty_max_minus_0", "duty_max_pct = 100.0", "duty_max_pct = -0.0", False, "duty_"),
    ("rate_pct_per_s_1e308_legal", "rate_pct_per_s = 10000.0", "rate_pct_per_s = 1e308", None, "rate_pct_per_s"),
    ("status_above_rate", "status_hz = 10.0", "status_hz = 2000.0", False, "status_hz"),
    ("spin_above_period", "spin_us = 50.0", "spin_us = 1000.0", False, "spin_us"),
    ("rt_priority_100", "rt_priority = 20", "rt_priority = 100", False, "rt_priority"),
    ("rt_priority_float", "rt_priority = 20", "rt_priority = 20.5", False, "rt_priority"),
    ("cpu_4095", "rt_priority = 20", "rt_priority = 20\ncpu = 4095", None, "cpu"),
    ("cpu_minus_2", "rt_priority = 20", "rt_priority = 20\ncpu = -2", False, "cpu"),
    ("trigger_word", 'trigger = "period"', 'trigger = "Period"', False, "trigger"),
    ("trigger_measurement_sim", 'trigger = "period"', 'trigger = "measurement"', False, "measurement"),
    ("rehearse_string", "rehearse = true", 'rehearse = "true"', False, "rehearse"),
    ("catch_up_int", "catch_up = true", "catch_up = 1", False, "catch_up"),
    ("controller_word_case", 'controller = "ff+kf"', 'controller = "FF+KF"', False, "controller"),
    ("plant_int", 'plant = "sim"', "plant = 1", False, "plant"),
    ("duration_1e308", "duration_s = 20.0", "duration_s = 1e308", False, "duration"),
    ("seed_2_63", "seed = 0 ", "seed = 9223372036854775807 ", True, ""),
    ("seed_float_legal_int", "seed = 0 ", "seed = 1.0 ", None, "seed"),
    ("model_dev_zero", 'model = "valve_model.json"', 'model = "/dev/zero"', False, "/dev/zero"),
    ("model_dev_urandom", 'model = "valve_model.json"', 'model = "/dev/urandom"', False, "/dev/urandom"),
    ("model_a_folder", 'model = "valve_model.json"', 'model = "valves"', False, "valves"),
    ("model_proc_text", 'model = "valve_model.json"', 'model = "/proc/self/status"', False, "status"),
    ("model_bouc_wen_for_ff", 'model = "valve_model.json"', 'model = "@bouc-wen"', False, "bouc-wen"),
    ("plant_config_dev_zero", 'plant_config = "valves/bench/plant.toml"', 'plant_config = "/dev/zero"', False,
     "/dev/zero"),
    ("plant_config_self", 'plant_config = "valves/bench/plant.toml"', 'plant_config = "run.toml"', False,
     "run.toml"),
    ("profile_kind_int", 'kind = "square"', "kind = 3", False, "kind"),
    ("profile_peak_string", "peak_lpm = 60.0", 'peak_lpm = "60"', False, "peak_lpm"),
    ("profile_peak_above_flow_max", "peak_lpm = 60.0", "peak_lpm = 250.0", False, "peak_lpm"),
    ("profile_unknown_key", "ie_ratio = 0.5", "ie_ratio = 0.5\npeak = 80.0", False, "peak"),
    ("profile_ie_ratio_1e308", "ie_ratio = 0.5", "ie_ratio = 1e308", None, "ie_ratio"),
    ("profile_end_fraction_2", "ie_ratio = 0.5", 'ie_ratio = 0.5\nkind_ = 1', False, "kind_"),
    ("profile_rise_longer_than_breath", "ie_ratio = 0.5", "ie_ratio = 0.5\nrise_s = 100.0", None, "rise_s"),
    ("profile_end_fraction_negative", 'kind = "square"', 'kind = "ramp"\nend_fraction = -1.0', False,
     "end_fraction"),
    ("profile_end_fraction_nan", 'kind = "square"', 'kind = "ramp"\nend_fraction = nan', False, "end_fraction"),
    ("profile_base_above_peak", "ie_ratio = 0.5", "ie_ratio = 0.5\nbase_lpm = 90.0", None, "base_lpm"),
    ("effects_bool", "valve_dynamics = 0.02", "valve_dynamics = true", False, "valve_dynamics"),
    ("effects_table", "valve_dynamics = 0.02", "valve_dynamics = {tau = 0.02}", False, "valve_dynamics"),
    ("effects_at_limit_60", "valve_dynamics = 0.02", "valve_dynamics = 60.0", None, "valve_dynamics"),
    ("effects_past_limit", "transport_delay = 0.02", "transport_delay = 10.000001", False, "transport_delay"),
    ("effects_dead_zone_100", "transport_delay = 0.02", "transport_delay = 0.02\ndead_zone = 100.0", None,
     "dead_zone"),
    ("valve_tau_61", "tau_s = 0.02 ", "tau_s = 61.0 ", False, "tau_s"),
    ("lead_lag_0", "lead_lag_s = 0.003", "lead_lag_s = 0.0", False, "lead_lag_s"),
    ("ready_margin_101", "ready_margin_pct = 2.0", "ready_margin_pct = 101.0", False, "ready_margin_pct"),
    ("pid_kp_negative", "kp = 0.2", "kp = -0.2", False, "kp"),
    ("pid_tt_0", "tt_s = 0.01", "tt_s = 0.0", False, "tt_s"),
    ("kf_r_1e5", "r_lpm = 0.5", "r_lpm = 1e5", False, "r_lpm"),
    ("kf_q_negative", "q_flow_lpm = 1.0", "q_flow_lpm = -1.0", False, "q_flow_lpm"),
    ("zenoh_id_space", 'id = "insp"', 'id = "in sp"', False, "id"),
    ("zenoh_id_dollar", 'id = "insp"', 'id = "$*"', False, "id"),
    ("zenoh_id_unicode", 'id = "insp"', 'id = "inspé"', False, "id"),
    ("zenoh_id_65_chars", 'id = "insp"', f'id = "{"a" * 65}"', False, "id"),
    ("zenoh_listen_empty_list_sim_legal", 'listen = ["tcp/127.0.0.1:7447"]', "listen = []", True, ""),
    ("zenoh_listen_number", 'listen = ["tcp/127.0.0.1:7447"]', "listen = [7447]", False, "listen"),
    ("zenoh_config_missing_file", 'config = "zenoh.json5"', 'config = "nope.json5"', None, "nope.json5"),
    ("zenoh_config_broken", 'config = "zenoh.json5"', 'config = "run.toml"', None, "run.toml"),  # read when used
    ("zenoh_config_dev_zero", 'config = "zenoh.json5"', 'config = "/dev/zero"', None, "/dev/zero"),
    ("zenoh_io_priority_100", "io_priority = 10", "io_priority = 100", False, "io_priority"),
    ("zenoh_io_nice_20", "io_nice = 0", "io_nice = 20", False, "io_nice"),
    ("node_rate_0", "[valve_node]\nrate_hz = 1000.0", "[valve_node]\nrate_hz = 0.0", False, "rate_hz"),
    ("node_timeout_1e308", "command_timeout_ms = 100.0", "command_timeout_ms = 1e308", False, "command_timeout_ms"),
    ("node_aux_hz_1e308", "aux_hz = 50.0", "aux_hz = 1e308", False, "aux_hz"),
    ("node_aux_above_rate", "aux_hz = 50.0", "aux_hz = 5000.0", False, "aux_hz"),
    ("alarms_unknown", "supply_low_bar = 2.0", "supply_low_bar = 2.0\nsupply_high_bar = 9.0", False,
     "supply_high_bar"),
    ("alarms_supply_low_minus_1e308", "supply_low_bar = 2.0", "supply_low_bar = -1e308", False, "supply_low_bar"),
    ("alarms_hold_1e308", "saturated_hold_s = 0.1", "saturated_hold_s = 1e308", None, "saturated_hold_s"),
    ("fallback_limit_0", "innovation_limit_lpm = 10.0", "innovation_limit_lpm = 0.0", False,
     "innovation_limit_lpm"),
    ("identify_stale_ms_1e308", "stale_ms = 250.0", "stale_ms = 1e308", False, "stale_ms"),
    ("identify_flow_limit_1e308", "flow_limit_lpm = 200.0", "flow_limit_lpm = 1e308", False, "flow_limit_lpm"),
    ("identify_wait_1e308", "wait_s = 10.0", "wait_s = 1e308", False, "wait_s"),
    ("identify_duration_9", "duration_s = 600.0", "duration_s = 9.0", False, "duration_s"),
    ("identify_tune_0", "tune_candidates = 200", "tune_candidates = 0", False, "tune_candidates"),
    ("empty_file", "", None, None, ""),  # every default
    ("binary_file", "", b"\x00\xff\xfe" * 100, False, "run.toml"),
]

PLANT_TOML_EDITS = [
    ("model_missing_key", 'model = "valve_pi_asym.json"', "", False, "model"),
    ("unknown_key_sensor", "noise_lpm = 0.5", "noise_lpm = 0.5\nnoise = 3.0", False, "noise"),
    ("sensor_range_reversed", "range_lpm = [-250.0, 250.0]", "range_lpm = [250.0, -250.0]", False, "range_lpm"),
    ("sensor_range_three", "range_lpm = [-250.0, 250.0]", "range_lpm = [-250.0, 0.0, 250.0]", False, "range_lpm"),
    ("sensor_range_strings", "range_lpm = [-250.0, 250.0]", 'range_lpm = ["-250", "250"]', False, "range_lpm"),
    ("scale_factor_0_legal", "scale_factor = 120.0", "scale_factor = 0.0", True, ""),
    ("scale_factor_1e308", "scale_factor = 120.0", "scale_factor = 1e308", False, "scale_factor"),
    ("noise_1e308", "noise_lpm = 0.5", "noise_lpm = 1e308", False, "noise_lpm"),
    ("supply_below_vacuum", "supply_bar = 3.0", "supply_bar = -2.0", False, "supply_bar"),
    ("model_supply_nan", "model_supply_bar = 3.0", "model_supply_bar = nan", False, "model_supply_bar"),
    ("atmosphere_0", "atmosphere_bar = 1.01325", "atmosphere_bar = 0.0", False, "atmosphere_bar"),
    ("droop_negative", "droop_bar = 0.15", "droop_bar = -0.15", False, "droop_bar"),
    ("coil_alpha_inf", "coil_alpha_per_k = 0.00393", "coil_alpha_per_k = inf", False, "coil_alpha_per_k"),
    ("ambient_below_zero_k", "ambient_c = 25.0", "ambient_c = -300.0", False, "ambient_c"),
    ("dynamics_order_0", "dynamics_order = 1", "dynamics_order = 0", False, "dynamics_order"),
    ("dynamics_order_2_legal", "dynamics_order = 1", "dynamics_order = 2", True, ""),
    ("creep_tau_negative", "creep_tau_s = 20.0", "creep_tau_s = -20.0", False, "creep_tau_s"),
    ("effect_unknown", "\n[effects]", "\n[effects]\nwarp_drive = 1.0", False, "warp_drive"),
    ("effect_string", "saturation = 0.0", 'saturation = "150"', False, "saturation"),
    ("effect_saturation_negative", "saturation = 0.0", "saturation = -1.0", False, "saturation"),
    ("section_unknown", "[coil]", "[coils]", False, "coils"),
    ("model_dev_zero", 'model = "valve_pi_asym.json"', 'model = "/dev/zero"', False, "/dev/zero"),
    ("model_fifo", 'model = "valve_pi_asym.json"', 'model = "@fifo"', False, "fifo"),
    ("model_symlink_loop", 'model = "valve_pi_asym.json"', 'model = "@loop"', False, "loop"),
]

SWEEP_SMALL = """run = "run.toml"
duration_s = 0.3
seed = 0
objective = "iae"
margins_top = 1
chunk_loops = 8

[profile]
peak_lpm = 60.0

[[variants]]

[[candidates]]
controller = "pid"
sample = 2
pid.kp = {log = [0.03, 1.0]}
"""

SWEEP_EDITS = [
    ("candidate_rate_hz_0", "pid.kp = {log", "loop.rate_hz = {uniform = [0.0, 0.0]}\npid.kp = {log", False, "rate_hz"),
    ("candidate_stale_nan", "pid.kp = {log", "loop.stale_ms = [nan]\npid.kp = {log", False, "stale_ms"),
    ("candidate_duty_max_200", "pid.kp = {log", "limits.duty_max_pct = {uniform = [90.0, 200.0]}\npid.kp = {log",
     False, "duty_max_pct"),
    ("candidate_unknown_section", "pid.kp = {log", "pidd.kp = [0.1]\npid.kp = {log", False, "pidd"),
    ("candidate_log_zero", "{log = [0.03, 1.0]}", "{log = [0.0, 1.0]}", False, "kp"),
    ("candidate_log_huge", "{log = [0.03, 1.0]}", "{log = [1e-300, 1e308]}", False, "kp"),
    ("candidate_uniform_degenerate", "{log = [0.03, 1.0]}", "{uniform = [0.5, 0.5]}", None, "kp"),
    ("candidate_uniform_three", "{log = [0.03, 1.0]}", "{uniform = [0.1, 0.5, 0.9]}", False, "kp"),
    ("candidate_two_kinds", "{log = [0.03, 1.0]}", "{log = [0.03, 1.0], uniform = [0.1, 0.2]}", False, "kp"),
    ("candidate_empty_list", "{log = [0.03, 1.0]}", "[]", False, "kp"),
    ("candidate_strings", "{log = [0.03, 1.0]}", '["0.1", "0.2"]', False, "kp"),
    ("candidate_model_missing", "pid.kp = {log", 'model = ["nope.json"]\npid.kp = {log', False, "nope.json"),
    ("candidate_model_empty", "pid.kp = {log", "model = []\npid.kp = {log", False, "model"),
    ("candidate_controller_missing", 'controller = "pid"\n', "", False, "controller"),
    ("candidate_sample_float", "sample = 2", "sample = 2.5", False, "sample"),
    ("candidate_sample_huge", "sample = 2", "sample = 10000000000", False, "sample"),
    ("variant_string", "[[variants]]", '[[variants]]\nsupply_bar = "3"', False, "supply_bar"),
    ("variant_effect_past_limit", "[[variants]]", "[[variants]]\ndead_zone = 101.0", False, "dead_zone"),
    ("variant_nested_table", "[[variants]]", "[[variants]]\nsensor = {noise_lpm = 1.0}", None, "sensor"),
    ("run_self", 'run = "run.toml"', 'run = "s.toml"', False, "s.toml"),
    ("run_dev_zero", 'run = "run.toml"', 'run = "/dev/zero"', False, "/dev/zero"),
    ("run_is_folder", 'run = "run.toml"', 'run = "valves"', False, "valves"),
    ("duration_shorter_than_a_step", "duration_s = 0.3", "duration_s = 1e-9", False, "duration_s"),
    ("heatmap_unknown", "chunk_loops = 8", 'chunk_loops = 8\nheatmap = ["pid.kq", "pid.ki"]', False, "heatmap"),
    ("heatmap_one", "chunk_loops = 8", 'chunk_loops = 8\nheatmap = ["pid.kp"]', False, "heatmap"),
    ("heatmap_string", "chunk_loops = 8", 'chunk_loops = 8\nheatmap = "pid.kp"', False, "heatmap"),
    ("top_unknown", "chunk_loops = 8", "chunk_loops = 8\nworkers = 2", False, "workers"),
    ("objective_int", 'objective = "iae"', "objective = 1", False, "objective"),
    ("margins_top_float", "margins_top = 1", "margins_top = 1.5", False, "margins_top"),
    ("profile_peak_string", "peak_lpm = 60.0", 'peak_lpm = "60"', False, "peak_lpm"),
    ("profile_unknown", "peak_lpm = 60.0", "peak_lpm = 60.0\npeak = 1.0", False, "peak"),
    ("no_variants_legal", "[[variants]]\n", "", None, "variants"),
    ("as_is", "seed = 0", "seed = 0", True, ""),
]


def _special_files(folder: str) -> dict[str, str]:
    """Paths of files no one should have to read: FIFO, sparse giant, symlink loop, dangling link..."""
    os.makedirs(folder, exist_ok=True)
    s = {}
    s["fifo"] = os.path.join(folder, "fifo.csv")
    if not os.path.exists(s["fifo"]):
        os.mkfifo(s["fifo"])
    s["sparse"] = os.path.join(folder, "sparse.csv")
    with open(s["sparse"], "wb") as fh:
        fh.write(b"t_s,duty_pct,flow_lpm\n0,50,10\n")
        fh.truncate(64 << 30)  # 64 GiB of holes after two lines
    s["loop"] = os.path.join(folder, "loop.csv")
    if not os.path.lexists(s["loop"]):
        os.symlink(s["loop"] + ".b", s["loop"])
        os.symlink(s["loop"], s["loop"] + ".b")
    s["dangling"] = os.path.join(folder, "dangling.csv")
    if not os.path.lexists(s["dangling"]):
        os.symlink(os.path.join(folder, "gone", "x.csv"), s["dangling"])
    s["zero"], s["urandom"], s["null"], s["proc"] = "/dev/zero", "/dev/urandom", "/dev/null", "/proc/self/status"
    s["fifo_out"] = os.path.join(folder, "out.fifo")
    if not os.path.exists(s["fifo_out"]):
        os.mkfifo(s["fifo_out"])
    # devices as outputs through symlinks: a writer that renames over the path replaces the link, not /dev/null
    for name, dev in (("devnull", "/dev/null"), ("devfull", "/dev/full")):
        s[name] = os.path.join(folder, name)
        if not os.path.lexists(s[name]):
            os.symlink(dev, s[name])
    s["newline"] = os.path.join(folder, "bad\nname.csv")
    with open(s["newline"], "w") as fh:
        fh.write("t_s,duty_pct\n0,abc\n")
    s["folder"] = folder
    return s


def cases(models: dict[str, dict], special: dict[str, str]) -> list[XCase]:
    out: list[XCase] = []
    # -- recordings, through every verb that reads one
    verbs = {
        "fit-pi-mod": (["fit", "{d}/rec.csv", "--model", "pi-mod", "--n", "8", "-o", "{d}/m.json"], "rec", 60),
        "compare": (["compare", "{d}/rec.csv", "--json", "{d}/c.json"], "rec", 60),
        "diagnose": (["diagnose", "{d}/rec.csv", "--json", "{d}/d.json"], "rec", 60),
        "simulate-protocol": (["simulate", "--protocol", "{d}/rec.csv", "--duration", "2", "-o", "{d}/s.csv"],
                              "proto", 30),
        "run-reference": (["run", "--reference", "{d}/rec.csv", "--duration", "0.3"], "ref", 30),
        "run-reference-own-length": (["run", "--reference", "{d}/rec.csv", "--controller", "pid"], "ref", 30),
    }
    for name, content, legal_for, expect in recordings():
        for verb, (argv, klass, timeout) in verbs.items():
            if verb == "run-reference-own-length" and not name.startswith(("time_", "one_row", "good")):
                continue
            legal = klass in legal_for
            if verb == "run-reference-own-length" and name == "one_row":
                legal = False  # a span of 0 s sets no run length
            out.append(XCase(f"recording/{name}/{verb}", list(argv), {"rec.csv": content},
                             legal=legal, expect=expect, timeout=timeout))
    good_rec = csv_text(base_recording())
    for kind in KINDS:  # every kind fitted on a bad recording of each shape class
        for name in ("good", "one_row", "constant_flow", "time_1e14_hz", "time_gap_1e9_s_mid", "nineteen_rows",
                     "quoted_cells", "columns_reordered"):
            content, legal_for = next((c, lf) for n, c, lf, _ in recordings() if n == name)
            out.append(XCase(f"recording/{name}/fit-{kind}", ["fit", "{d}/rec.csv", "--model", kind, "-o",
                                                               "{d}/m.json"], {"rec.csv": content},
                             legal="rec" in legal_for, expect="rec.csv", timeout=60))
    for label, path in special.items():
        if label in ("folder", "fifo_out", "devnull", "devfull"):
            continue
        exp = "bad" if label == "newline" else os.path.basename(path)
        for verb, argv in {"fit": ["fit", path, "--model", "pi", "-o", "{d}/m.json"],
                           "compare": ["compare", path, "--json", "{d}/c.json"],
                           "diagnose-model": ["diagnose", "{d}/rec.csv", "--model", path, "--json", "{d}/d.json"],
                           "simulate-protocol": ["simulate", "--protocol", path, "--duration", "1", "-o", "{d}/s.csv"],
                           "run-reference": ["run", "--reference", path, "--duration", "0.2"],
                           "run-config": ["run", "--config", path, "--duration", "0.2"],
                           "simulate-plant": ["simulate", "--plant", path, "--duration", "1", "-o", "{d}/s.csv"],
                           "sweep-config": ["sweep", "--config", path, "-o", "{d}/s.csv", "--workers", "1"],
                           "monitor-config": ["monitor", "--config", path, "--duration", "0.3"],
                           "valve-node-config": ["valve-node", "--config", path, "--duration", "0.3"],
                           "identify-config": ["identify", "--config", path, "-o", "{d}/id"]}.items():
            out.append(XCase(f"special/{label}/{verb}", argv, {"rec.csv": good_rec}, legal=False, expect=exp))

    # -- model files of every kind
    for name, text, legal, expect in model_mutations(models):
        kind = name.split("/")[0]
        invertible = kind in ("pi", "pi-asym", "pi-mod", "preisach")
        out.append(XCase(f"model/{name}/diagnose", ["diagnose", "{d}/rec.csv", "--model", "{d}/m.json", "--json",
                                                    "{d}/d.json"], {"m.json": text, "rec.csv": good_rec},
                         legal=legal, expect=expect, timeout=60))
        plant = 'model = "m.json"\n'
        run_expect = "valve_model.json" if expect == "m.json" else expect
        out.append(XCase(f"model/{name}/simulate-plant", ["simulate", "--plant", "{d}/plant.toml", "--duration", "2",
                                                          "-o", "{d}/s.csv"],
                         {"m.json": text, "plant.toml": plant}, legal=legal, expect=expect))
        if invertible:
            out.append(XCase(f"model/{name}/run-ff", ["run", "--config", "{d}/config/run.toml", "--controller", "ff",
                                                      "--duration", "0.2"],
                             {"config/valve_model.json": text}, legal=legal, expect=run_expect, config=True))
        else:
            out.append(XCase(f"model/{name}/run-ff-not-invertible",
                             ["run", "--config", "{d}/config/run.toml", "--controller", "ff", "--duration", "0.2"],
                             {"config/valve_model.json": text}, legal=False,
                             expect="model", config=True))

    # -- run.toml, through run, valve-node, monitor and identify
    base_run = open(os.path.join(ROOT, "config", "run.toml"), encoding="utf-8").read()
    for name, find, repl, legal, expect in RUN_TOML_EDITS:
        if isinstance(repl, bytes) or repl is None:
            files = {"config/run.toml": repl if repl is not None else ""}
        else:
            repl = (repl.replace("@bouc-wen", os.path.join(special["folder"], "bouc-wen.json")))
            if find not in base_run:
                raise KeyError(f"{name}: {find!r} not in run.toml")
            files = {"config/run.toml": ("edit", find, repl)}
        expect = expect or ""
        out.append(XCase(f"run.toml/{name}/run", ["run", "--config", "{d}/config/run.toml", "--duration", "0.2"],
                         files, legal=legal, expect=expect, config=True))
        if name.startswith(("loop.", "zenoh", "node_", "valve_node", "section", "duplicate", "date", "empty",
                            "binary", "identify_", "top_level")):
            out.append(XCase(f"run.toml/{name}/valve-node",
                             ["valve-node", "--config", "{d}/config/run.toml", "--duration", "0.3",
                              "--listen", "tcp/127.0.0.1:{port}", "--connect", "tcp/127.0.0.1:{port2}"],
                             files, legal=legal if not name.startswith("identify_") else legal, expect=expect,
                             config=True))
        if name.startswith(("identify_", "zenoh_id", "empty", "binary")):
            out.append(XCase(f"run.toml/{name}/identify",
                             ["identify", "--config", "{d}/config/run.toml", "--duration", "10", "-o", "{d}/id",
                              "--listen", "tcp/127.0.0.1:{port}"], files, legal=None if legal else False,
                             expect=expect, config=True, timeout=30, long_ok=bool(legal)))
        if name.startswith(("zenoh", "empty", "binary")):
            out.append(XCase(f"run.toml/{name}/monitor",
                             ["monitor", "--config", "{d}/config/run.toml", "--duration", "0.3",
                              "--connect", "tcp/127.0.0.1:{port}"], files, legal=legal, expect=expect, config=True))
    # the valves' own files
    for valve in sorted(os.listdir(os.path.join(ROOT, "config", "valves"))):
        vdir = f"config/valves/{valve}"
        vrun = open(os.path.join(ROOT, vdir, "run.toml"), encoding="utf-8").read()
        vplant = open(os.path.join(ROOT, vdir, "plant.toml"), encoding="utf-8").read()
        out.append(XCase(f"valves/{valve}/run.toml/as_shipped", ["run", "--config", f"{{d}}/{vdir}/run.toml",
                                                                 "--duration", "0.2"], {}, legal=True, config=True))
        for name, find, repl, legal, expect in RUN_TOML_EDITS[:12]:
            if isinstance(repl, bytes) or repl is None or find not in vrun:
                continue
            out.append(XCase(f"valves/{valve}/run.toml/{name}", ["run", "--config", f"{{d}}/{vdir}/run.toml",
                                                                  "--duration", "0.2"],
                             {f"{vdir}/run.toml": ("edit", find, repl)}, legal=legal, expect=expect, config=True))
        model_line = re.search(r'^model = "[^"]*"', vplant, re.M).group(0)
        for name, find, repl, legal, expect in PLANT_TOML_EDITS:
            find = model_line if find.startswith("model = ") else find
            if find not in vplant:
                continue
            repl = repl.replace("@fifo", special["fifo"]).replace("@loop", special["loop"])
            if name == "model_missing_key":
                repl = ""
            out.append(XCase(f"valves/{valve}/plant.toml/{name}", ["simulate", "--plant", f"{{d}}/{vdir}/plant.toml",
                                                                    "--duration", "2", "-o", "{d}/s.csv"],
                             {f"{vdir}/plant.toml": ("edit", find, repl)}, legal=legal, expect=expect, config=True))
    # sweep specs
    for name, find, repl, legal, expect in SWEEP_EDITS:
        out.append(XCase(f"sweep.toml/{name}/sweep", ["sweep", "--config", "{d}/config/s.toml", "-o", "{d}/s.csv",
                                                      "--workers", "1"],
                         {"config/s.toml": ("edit", find, repl, SWEEP_SMALL)}, legal=legal, expect=expect,
                         config=True, timeout=60))

    # -- CLI arguments
    rec = {"rec.csv": good_rec}
    A = []

    def arg(name, argv, files=None, legal=False, expect="", timeout=30.0, long_ok=False):
        A.append(XCase(f"args/{name}", argv, dict(files or {}), legal=legal, expect=expect, timeout=timeout,
                       long_ok=long_ok, config=any("{d}/config" in a for a in argv)))

    for inj, legal, exp in [("supply_bar=0.3", False, "inject"), ("@1", False, "inject"), ("=1@1", False, "inject"),
                            ("supply_bar=inf@1", False, "inject"), ("supply_bar=1@inf", False, "inject"),
                            ("supply_bar=1@-1", False, "inject"), ("supply_bar=1e308@0.1", False, "supply_bar"),
                            ("supply_bar=-5@0.1", False, "supply_bar"), ("dead_zone=150@0.1", False, "dead_zone"),
                            ("transport_delay=1e9@0.1", False, "transport_delay"),
                            ("valve_dynamics=-1@0.1", False, "valve_dynamics"), ("noise_lpm=-1@0.1", False, "noise"),
                            ("noise_lpm=1e308@0.1", False, "noise"), ("model=1@0.1", False, "model"),
                            ("seed=5@0.1", False, "seed"), ("dead_zone=20@0.1", True, ""),
                            ("supply_bar=0.3@1e308", None, ""), ("supply_bar=0x10@1", False, "inject"),
                            ("supply_bar=1@1@2", False, "inject"), ("  dead_zone = 5 @ 0.1 ", None, "dead_zone"),
                            ("sensor_offset=1e6@0.1", False, "sensor_offset"), ("creep=nan@0.1", False, "inject"),
                            ("saturation=1e-320@0.1", None, "saturation"), ("coil_heating=201@0", False,
                                                                             "coil_heating")]:
        arg(f"run --inject {inj}", ["run", "--duration", "0.3", "--inject", inj], legal=legal, expect=exp)
    from plant_sim.effects import EFFECTS
    for word, e in EFFECTS.items():
        lo, hi = e.limits
        arg(f"simulate --effect {word} alone", ["simulate", "--effect", word, "--duration", "2", "-o", "{d}/s.csv"],
            legal=True)
        arg(f"simulate --effect {word} at upper limit", ["simulate", "--effect", f"{word}={hi!r}", "--duration", "2",
                                                         "-o", "{d}/s.csv"], legal=None, expect=word)
        arg(f"simulate --effect {word} past upper limit", ["simulate", "--effect", f"{word}={hi * 1.000001 + 1e-9!r}",
                                                           "--duration", "2", "-o", "{d}/s.csv"], expect=word)
        arg(f"simulate --effect {word} below lower limit", ["simulate", "--effect", f"{word}={lo - 1e-6!r}",
                                                            "--duration", "2", "-o", "{d}/s.csv"], expect=word)
        arg(f"simulate --effect {word} inf", ["simulate", "--effect", f"{word}=inf", "--duration", "2", "-o",
                                              "{d}/s.csv"], expect=word)
        arg(f"simulate --effect {word} twice", ["simulate", "--effect", f"{word}", "--effect", f"{word}=0",
                                                "--duration", "2", "-o", "{d}/s.csv"], legal=None, expect=word)
    for spec, exp in [("dead_zone==5", "dead_zone"), ("dead_zone=5=6", "dead_zone"), ("DEAD_ZONE=5", "DEAD_ZONE"),
                      ("dead_zone=", "dead_zone"), ("dead_zone=5%", "dead_zone"), ("dead zone=5", "dead zone"),
                      ("=5", "effect"), ("dead_zone=0x5", "dead_zone"), ("dead_zone=1e-320", ""),
                      ("dead_zone=5,saturation=100", "dead_zone")]:
        arg(f"simulate --effect '{spec}'", ["simulate", "--effect", spec, "--duration", "2", "-o", "{d}/s.csv"],
            legal=None if spec == "dead_zone=1e-320" else False, expect=exp)
    for proto in ("paper_identification", "steps", "ramps", "random_holds", "sines"):
        arg(f"simulate --protocol {proto} --duration 0.001", ["simulate", "--protocol", proto, "--duration", "0.001",
                                                              "-o", "{d}/s.csv"], legal=None, expect="duration")
        arg(f"simulate --protocol {proto} --rate 0.5 --duration 1", ["simulate", "--protocol", proto, "--rate", "0.5",
                                                                     "--duration", "1", "-o", "{d}/s.csv"], legal=None,
            expect="")
    arg("simulate 99.9M rows", ["simulate", "--rate", "100000", "--duration", "999", "-o", "{d}/s.csv"],
        legal=None, expect="duration", timeout=60)
    arg("simulate 1e8+1 rows", ["simulate", "--rate", "100000", "--duration", "1000.00001", "-o", "{d}/s.csv"],
        expect="duration")
    arg("simulate --seed 2**63", ["simulate", "--seed", str(2**63), "--duration", "1", "-o", "{d}/s.csv"],
        expect="seed")
    arg("simulate --seed 2**63-1", ["simulate", "--seed", str(2**63 - 1), "--duration", "1", "-o", "{d}/s.csv"],
        legal=True)
    arg("simulate --seed 1.5", ["simulate", "--seed", "1.5", "-o", "{d}/s.csv"], expect="seed")
    arg("simulate --duration 1e-300", ["simulate", "--duration", "1e-300", "-o", "{d}/s.csv"], legal=None,
        expect="duration")
    # output paths
    outs = {"/proc/x": "/proc/x", "dev null": special["devnull"], "dev full": special["devfull"],
            "long name": "{d}/" + "n" * 300 + ".csv",
            "dangling symlink": special["dangling"], "trailing slash": "{d}/out/", "root": "/",
            "empty string": "", "fifo": special["fifo_out"], "newline in name": "{d}/a\nb.csv"}
    for label, path in outs.items():
        legal = None if label in ("dangling symlink", "newline in name") else False  # odd, but writable names
        exp = {"empty string": "", "newline in name": "", "dev null": "null", "dev full": "full"}.get(
            label, path.split("/")[-1][:20] or "/")
        if label == "long name":
            exp = "nnnn"
        if label == "trailing slash":
            exp = "out"
        arg(f"simulate -o {label}", ["simulate", "--duration", "1", "-o", path], legal=legal, expect=exp)
        arg(f"fit -o {label}", ["fit", "{d}/rec.csv", "--model", "pi", "-o", path], rec, legal=legal, expect=exp)
        arg(f"compare --json {label}", ["compare", "{d}/rec.csv", "--json", path], rec, legal=legal, expect=exp,
            timeout=60)
        arg(f"run --json {label}", ["run", "--duration", "0.2", "--json", path], legal=legal, expect=exp)
        arg(f"run --record {label}", ["run", "--duration", "0.2", "--record", path], legal=legal, expect=exp)
        arg(f"diagnose --predictions {label}", ["diagnose", "{d}/rec.csv", "--json", "{d}/d.json", "--predictions",
                                                path], rec, legal=legal, expect=exp, timeout=60)
        if label != "root":  # certs into / would write the site's keys there
            arg(f"certs {label}", ["certs", path], legal=None if label == "trailing slash" else legal, expect=exp)
        arg(f"valve-node --json {label}", ["valve-node", "--duration", "0.3", "--json", path, "--listen",
                                           "tcp/127.0.0.1:{port}", "--connect", "tcp/127.0.0.1:{port2}"],
            legal=legal, expect=exp)
        arg(f"monitor --record {label}", ["monitor", "--duration", "0.3", "--record", path, "--connect",
                                          "tcp/127.0.0.1:{port}"], legal=legal, expect=exp)
    arg("identify -o /proc/x", ["identify", "--duration", "10", "-o", "/proc/x", "--listen", "tcp/127.0.0.1:{port}"],
        expect="/proc/x")
    arg("identify -o non-empty folder", ["identify", "--duration", "10", "-o", "{d}/id", "--listen",
                                         "tcp/127.0.0.1:{port}"], {"id/model.json": "{}"}, legal=None, expect="id",
        long_ok=True)
    arg("sweep --report /proc/x", ["sweep", "--config", "{d}/config/s.toml", "-o", "{d}/s.csv", "--workers", "1",
                                   "--report", "/proc/x"], {"config/s.toml": SWEEP_SMALL}, expect="/proc/x")
    arg("sweep --best-config dev full", ["sweep", "--config", "{d}/config/s.toml", "-o", "{d}/s.csv", "--workers",
                                          "1", "--best-config", special["devfull"]], {"config/s.toml": SWEEP_SMALL},
        expect="full", timeout=60)
    arg("sweep --workers 100000", ["sweep", "--config", "{d}/config/s.toml", "-o", "{d}/s.csv", "--workers",
                                   "100000"], {"config/s.toml": SWEEP_SMALL}, legal=None, expect="workers",
        timeout=60)
    arg("sweep --scheduler unreachable", ["sweep", "--config", "{d}/config/s.toml", "-o", "{d}/s.csv",
                                          "--scheduler", "tcp://127.0.0.1:{port}"], {"config/s.toml": SWEEP_SMALL},
        expect="scheduler", timeout=60)
    arg("sweep --scheduler garbage", ["sweep", "--config", "{d}/config/s.toml", "-o", "{d}/s.csv",
                                      "--scheduler", "not an address"], {"config/s.toml": SWEEP_SMALL},
        expect="scheduler", timeout=60)
    # durations: legal but long runs must not allocate their length up front; absurd ones are refused
    arg("run --duration 1e6 (legal, long)", ["run", "--duration", "1e6", "--controller", "pid"], legal=None,
        expect="duration", timeout=12, long_ok=True)
    arg("run --duration 1e308", ["run", "--duration", "1e308"], expect="duration")
    arg("run --duration 1e-9", ["run", "--duration", "1e-9"], legal=True)
    arg("monitor --duration inf", ["monitor", "--duration", "inf", "--connect", "tcp/127.0.0.1:{port}"],
        expect="duration")
    arg("monitor --duration 1e308", ["monitor", "--duration", "1e308", "--connect", "tcp/127.0.0.1:{port}"],
        legal=None, expect="duration", timeout=10, long_ok=True)
    arg("valve-node --duration 1e308", ["valve-node", "--duration", "1e308", "--listen", "tcp/127.0.0.1:{port}",
                                        "--connect", "tcp/127.0.0.1:{port2}"], legal=None, expect="duration",
        timeout=10, long_ok=True)
    arg("identify --duration 9", ["identify", "--duration", "9", "-o", "{d}/id", "--listen", "tcp/127.0.0.1:{port}"],
        expect="duration")
    arg("identify --duration 1e9", ["identify", "--duration", "1e9", "-o", "{d}/id", "--listen",
                                    "tcp/127.0.0.1:{port}"], expect="duration")
    arg("identify --duration inf", ["identify", "--duration", "inf", "-o", "{d}/id", "--listen",
                                    "tcp/127.0.0.1:{port}"], expect="duration")
    # endpoints
    for ep in ("tcp/127.0.0.1:99999", "tcp/127.0.0.1:-1", "udp/127.0.0.1:{port}x", "tcp/[::1", "tcp/",
               "unixsock-stream//proc/x/y", "tcp/256.0.0.1:7447", "quic/127.0.0.1:{port}", "tcp/127.0.0.1"):
        arg(f"run --plant zenoh --listen {ep}", ["run", "--plant", "zenoh", "--duration", "0.3", "--listen", ep],
            legal=None, expect="zenoh")
        arg(f"monitor --connect {ep}", ["monitor", "--duration", "0.3", "--connect", ep], legal=None, expect="zenoh")
    arg("run two controllers on one port", ["run", "--plant", "zenoh", "--duration", "0.3", "--listen",
                                            "tcp/127.0.0.1:{port}", "--listen", "tcp/127.0.0.1:{port}"], legal=None,
        expect="zenoh")
    # argparse
    for verb in ("fit", "compare", "simulate", "run", "valve-node", "sweep", "diagnose", "monitor", "certs",
                 "identify"):
        arg(f"{verb} --help", [verb, "--help"], legal=True)
        arg(f"{verb} --no-such-flag", [verb, "--no-such-flag"], expect="no-such-flag")
    arg("fit --model without value", ["fit", "{d}/rec.csv", "--model"], rec, expect="model")
    arg("fit extra positional", ["fit", "{d}/rec.csv", "{d}/rec.csv", "--model", "pi", "-o", "{d}/m.json"], rec,
        expect="unrecognized")
    arg("fit --model PI upper", ["fit", "{d}/rec.csv", "--model", "PI", "-o", "{d}/m.json"], rec, expect="PI")
    for kind, n in (("pi", "2001"), ("pi-mod", "2001"), ("pi-asym", "1"), ("preisach", "201"),
                    ("preisach-cont", "1000"), ("bouc-wen", "5"), ("pi-mod", "1"), ("preisach", "1")):
        arg(f"fit {kind} --n {n}", ["fit", "{d}/rec.csv", "--model", kind, "--n", n, "-o", "{d}/m.json"], rec,
            legal=None, expect="--n", timeout=60)
    arg("run --duration=", ["run", "--duration="], expect="duration")
    arg("run --reference missing", ["run", "--reference", "{d}/nope.csv", "--duration", "0.2"], expect="nope.csv")
    arg("run --reference word", ["run", "--reference", "stack", "--duration", "0.2"], expect="stack")
    arg("run --trigger measurement sim", ["run", "--trigger", "measurement", "--duration", "0.2"],
        expect="measurement")
    arg("run --inject with --plant zenoh", ["run", "--plant", "zenoh", "--inject", "dead_zone=5@0.1", "--duration",
                                            "0.2", "--listen", "tcp/127.0.0.1:{port}"], expect="inject")
    arg("compare --validate self", ["compare", "{d}/rec.csv", "--validate", "{d}/rec.csv", "--json", "{d}/c.json"],
        rec, legal=True, timeout=60)
    arg("compare --validate bad", ["compare", "{d}/rec.csv", "--validate", "{d}/v.csv", "--json", "{d}/c.json"],
        {**rec, "v.csv": "t_s,duty_pct,flow_lpm\n0,50,1\n"}, expect="v.csv", timeout=60)
    arg("diagnose --config bad", ["diagnose", "{d}/rec.csv", "--config", "{d}/r.toml", "--json", "{d}/d.json"],
        {**rec, "r.toml": "[loop]\nrate_hz = 0\n"}, expect="rate_hz", timeout=60)
    arg("diagnose --config unknown key", ["diagnose", "{d}/rec.csv", "--config", "{d}/r.toml", "--json",
                                          "{d}/d.json"], {**rec, "r.toml": "[loop]\nstale_msec = 10\n"},
        expect="stale_msec", timeout=60)
    for valve in sorted(os.listdir(os.path.join(ROOT, "config", "valves"))):
        arg(f"diagnose --config valves/{valve}", ["diagnose", "{d}/rec.csv", "--config",
                                                  f"{{d}}/config/valves/{valve}/run.toml", "--json", "{d}/d.json"],
            rec, legal=True, timeout=60)
    arg("diagnose --model and --config", ["diagnose", "{d}/rec.csv", "--model", "{d}/m.json", "--config",
                                          "{d}/config/run.toml", "--json", "{d}/d.json"],
        {**rec, "m.json": json.dumps(models["pi"])}, legal=False, expect="--model", timeout=60)
    for days, legal in (("1", True), ("0", False), ("36500", None), ("100000000", False)):
        arg(f"certs --days {days}", ["certs", "{d}/c", "--days", days], legal=legal, expect="days")
    for host, legal in (("*", None), ("1.2.3.4", True), ("::1", True), ("a" * 300, False), ("ü.example", None),
                        ("-", None), ("a..b", False)):
        arg(f"certs --host {host[:20]}", ["certs", "{d}/c", "--host", host], legal=legal, expect="host")
    arg("certs --site 300 chars", ["certs", "{d}/c", "--site", "s" * 300], legal=None, expect="site")
    arg("certs into existing certs", ["certs", "{d}/c"], {"c/ca.pem": "x", "c/ca.key": "y"}, legal=None,
        expect="c")
    arg("run --certs files of another site", ["run", "--plant", "zenoh", "--duration", "0.2", "--certs", "{d}/c",
                                              "--listen", "tcp/127.0.0.1:{port}"],
        {"c/ca.pem": "-----BEGIN CERTIFICATE-----\nAAAA\n-----END CERTIFICATE-----\n",
         "c/controller.pem": "", "c/controller.key": ""}, expect="c")
    out += A
    return out


# -- payloads, in-process -----------------------------------------------------------------------

def payloads() -> list[tuple[str, bytes]]:
    good = b'{"t": 1.0, "seq": 3, "value": 42.5}'
    p = [
        ("good", good), ("empty", b""), ("space", b" "), ("nul", b"\x00"), ("bom", b"\xef\xbb\xbf" + good),
        ("utf16", good.decode().encode("utf-16")), ("latin1_key", b'{"valu\xe9": 1}'),
        ("value_true", b'{"value": true}'), ("value_null", b'{"value": null}'), ("value_list", b'{"value": [1]}'),
        ("value_object", b'{"value": {"v": 1}}'), ("value_string_number", b'{"value": "42"}'),
        ("value_1e308", b'{"value": 1e308}'), ("value_minus_1e308", b'{"value": -1e308}'),
        ("value_1e309", b'{"value": 1e309}'), ("value_nan_word", b'{"value": NaN}'),
        ("value_infinity", b'{"value": Infinity}'), ("value_minus_infinity", b'{"value": -Infinity}'),
        ("value_19_digits", b'{"value": 1234567890123456789}'), ("value_4301_digits", b'{"value": ' + b"9" * 4301 + b"}"),
        ("value_subnormal", b'{"value": 5e-324}'), ("value_minus_zero", b'{"value": -0.0}'),
        ("value_hex", b'{"value": 0x10}'), ("value_leading_zero", b'{"value": 010}'),
        ("value_plus", b'{"value": +1}'), ("value_dot", b'{"value": .5}'),
        ("seq_float", b'{"value": 1, "seq": 1.0}'), ("seq_huge", b'{"value": 1, "seq": ' + b"9" * 30 + b"}"),
        ("seq_negative", b'{"value": 1, "seq": -1}'), ("seq_bool", b'{"value": 1, "seq": false}'),
        ("t_string", b'{"value": 1, "t": "now"}'), ("t_1e400", b'{"value": 1, "t": 1e400}'),
        ("src_number", b'{"value": 1, "src": 5}'), ("src_long", b'{"value": 1, "src": "' + b"a" * 10000 + b'"}'),
        ("duplicate_value", b'{"value": 1, "value": "x"}'), ("duplicate_value_rev", b'{"value": "x", "value": 1}'),
        ("extra_nested_ok", b'{"value": 1, "x": {"y": [1, 2]}}'), ("extra_deep", b'{"value": 1, "x": '
                                                                          + b"[" * 50 + b"]" * 50 + b"}"),
        ("deep_100k", b"[" * 100_000 + b"]" * 100_000), ("deep_in_string", b'{"value": 1, "s": "' + b"[" * 3000
                                                                       + b'"}'),
        ("brackets_unbalanced", b'{"value": 1, "x": [[[}'), ("escaped_quote", b'{"value": 1, "s": "\\"[[[["}'),
        ("lone_surrogate", b'{"value": 1, "s": "\\ud800"}'), ("control_char", b'{"value": 1, "s": "\x01"}'),
        ("trailing_comma", b'{"value": 1,}'), ("single_quotes", b"{'value': 1}"), ("array", b"[1, 2]"),
        ("number_only", b"42"), ("string_only", b'"42"'), ("big_payload", b'{"value": 1, "pad": "' + b"x" * 5000 + b'"}'),
        ("at_limit", b'{"value": 1, "pad": "' + b"x" * (4096 - 24) + b'"}'), ("meas_seq_string",
                                                                             b'{"value": 1, "meas_seq": "3"}'),
        ("meas_seq_huge", b'{"value": 1, "meas_seq": ' + b"9" * 40 + b"}"), ("word_value_empty", b'{"value": ""}'),
        ("word_value_long", b'{"value": "' + b"w" * 100 + b'"}'), ("word_unicode", b'{"value": "ff\\u202ekf"}'),
        ("two_objects", good + good), ("garbage_after", good + b"x"), ("whitespace_pad", b" \n\t" + good + b"\n "),
    ]
    return p


STATUSES = [
    ("status_good", {"state": "running", "controller": "ff+kf", "ref_lpm": 60.0, "flow_lpm": 59.0, "duty_pct": 50.0,
                     "error_lpm": 1.0, "alarms": [], "faults": {}}),
    ("status_extremes", {"state": "running", "ref_lpm": 1e308, "flow_lpm": -1e308, "duty_pct": 1e308,
                         "error_lpm": -1e308}),
    ("status_then_opposite", {"state": "running", "ref_lpm": -1e308, "flow_lpm": 1e308, "duty_pct": -1e308,
                              "error_lpm": 1e308}),
    ("status_state_newline", {"state": "run\nning,x", "controller": "a,b\nc"}),
    ("status_wrong_types", {"state": "fault", "controller": 5, "ref_lpm": "x", "flow_lpm": [1], "duty_pct": {},
                            "alarms": "saturated", "faults": [1, 2], "alarm_counts": 3, "steps": {"a": 1},
                            "lateness_us_max": "9", "iae": True}),
    ("status_alarms_objects", {"state": "safe", "alarms": [{"k": 1}, 5, None, "x" * 1000],
                               "faults": {"stale": {"n": 1}}, "alarm_counts": {"a": [1]}}),
    ("status_huge_ints", {"state": "running", "ref_lpm": 10**18 - 1, "steps": 10**18 - 1}),
    ("status_markup", {"state": "[bold red]x[/]", "controller": "[link=file:///etc/passwd]y[/link]"}),
]


def run_payloads(timeout_s: float = 5.0) -> list[tuple[str, str, str]]:
    """(name, outcome, detail) of every payload through every parser, and statuses through the monitor."""
    import io

    from rich.console import Console

    from controller.monitor import MonitorState, parse_status, render
    from controller.transport.guard import SourceGuard
    from controller.transport.payload import PayloadError, parse_command, parse_number, parse_word

    def alarm(*_):
        raise TimeoutError("hang")

    old = signal.signal(signal.SIGALRM, alarm)
    results = []
    try:
        for name, data in payloads():
            for pname, parse in (("number", parse_number), ("command", parse_command), ("word", parse_word),
                                 ("status", parse_status)):
                signal.setitimer(signal.ITIMER_REAL, timeout_s)
                try:
                    msg = parse(data)
                    ok = True
                    if pname in ("number", "command") and not (isinstance(msg.value, float)
                                                               and math.isfinite(msg.value)):
                        ok = False
                    if pname in ("number", "command") and msg.seq is not None and abs(msg.seq) >= 10**18:
                        ok = False
                    outcome = "clean" if ok else "accepted"
                    detail = repr(msg)[:80]
                except PayloadError as exc:
                    outcome, detail = "clean", str(exc)[:80]
                except TimeoutError:
                    outcome, detail = "hang", ""
                except BaseException as exc:  # noqa: BLE001 - the outcome under test
                    outcome, detail = "traceback", f"{type(exc).__name__}: {exc}"[:120]
                finally:
                    signal.setitimer(signal.ITIMER_REAL, 0)
                results.append((f"payload/{name}/{pname}", outcome, detail))
        guard = SourceGuard(0.5)
        for name, (src, seq) in {"src_none_seq_none": (None, None), "src_empty": ("", 1), "seq_back": ("a", 0),
                                 "seq_huge": ("a", 10**17), "seq_negative": ("a", -5), "second_src": ("b", 1)}.items():
            try:
                guard.believe(src, seq)
                results.append((f"guard/{name}", "clean", ""))
            except BaseException as exc:  # noqa: BLE001
                results.append((f"guard/{name}", "traceback", f"{type(exc).__name__}: {exc}"[:120]))
        m = MonitorState()
        for name, status in STATUSES:
            signal.setitimer(signal.ITIMER_REAL, timeout_s)
            try:
                data = json.dumps({"t": 1.0, "seq": 1, "value": status}).encode()
                msg = parse_status(data)
                row = m.add(msg.t_s, msg.value)
                Console(file=io.StringIO(), width=120).print(render(m, "test", 0.5, width=40))
                bad_row = any(isinstance(x, str) and ("\n" in x or "," in x) for x in row)
                results.append((f"monitor/{name}", "accepted" if bad_row else "clean",
                                "row cell breaks the CSV" if bad_row else ""))
            except PayloadError as exc:
                results.append((f"monitor/{name}", "clean", str(exc)[:80]))
            except TimeoutError:
                results.append((f"monitor/{name}", "hang", ""))
            except BaseException as exc:  # noqa: BLE001
                results.append((f"monitor/{name}", "traceback", f"{type(exc).__name__}: {exc}"[:120]))
            finally:
                signal.setitimer(signal.ITIMER_REAL, 0)
    finally:
        signal.signal(signal.SIGALRM, old)
    return results


# -- running ------------------------------------------------------------------------------------

def prepare(folder: str) -> tuple[dict, dict]:
    """Special files and one fitted model of every kind, in ``folder`` (kept for the children)."""
    special = _special_files(folder)
    rec = os.path.join(folder, "base.csv")
    with open(rec, "w") as fh:
        fh.write(csv_text(base_recording()))
    models = _fit_models(folder, rec)
    return models, special


def run_cases(selected: list[XCase], jobs: int, progress=None) -> list[tuple[XCase, str, object]]:
    """Every case in a forked child under :data:`MEMORY_LIMIT`, grouped by timeout; (case, outcome, result)."""
    from tests import battery

    child = battery._child

    def limited(*args):  # in the forked child only: the parent (a pytest worker) keeps its own limit
        resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, resource.getrlimit(resource.RLIMIT_AS)[1]))
        child(*args)

    battery._child = limited
    out = []
    try:
        for timeout in sorted({c.timeout for c in selected}):
            group = [c for c in selected if c.timeout == timeout]

            def each(r):
                o = judge(r.case, r.rc, r.stderr)
                out.append((r.case, o, r))
                if progress:
                    progress(r.case, o, r)

            run_battery(group, ROOT, timeout, jobs, each)
    finally:
        battery._child = child
    return out


def group_of(name: str) -> str:
    head = name.split("/")[0]
    if head == "args":
        return "args " + name.split("/", 1)[1].split()[0]
    if head in ("recording", "special", "model"):
        return f"{head} " + name.rsplit("/", 1)[-1]
    if head == "valves":
        return "valves " + name.split("/")[2]
    return head + " " + name.rsplit("/", 1)[-1] if head not in ("payload", "guard", "monitor") else head


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("-k", default="", help="only cases whose name contains this")
    ap.add_argument("-v", action="store_true", help="print every case")
    ap.add_argument("--json", default=None, help="write every case's outcome here")
    ap.add_argument("--list", action="store_true", help="list the cases and exit")
    a = ap.parse_args(argv)
    os.chdir(ROOT)
    folder = tempfile.mkdtemp(prefix="adversary-")
    t0 = time.monotonic()
    models, special = prepare(folder)
    selected = [c for c in cases(models, special) if a.k in c.name]
    if a.list:
        for c in selected:
            print(c.name)
        print(len(selected), "cases")
        return 0
    preload(ROOT)
    rows = []

    def progress(case, outcome, r):
        if a.v or outcome != "clean":
            last = (r.stderr.strip().splitlines() or [""])[-1][:160]
            print(f"{outcome:9s} rc={r.rc} {r.seconds:5.1f}s {case.name}: {last}", flush=True)

    for case, outcome, r in run_cases(selected, a.jobs, progress):
        rows.append({"case": case.name, "group": group_of(case.name), "legal": case.legal, "outcome": outcome,
                     "rc": r.rc, "seconds": round(r.seconds, 2), "stderr": r.stderr[-400:]})
    if not a.k or any(w in "payload monitor guard" for w in [a.k]):
        for name, outcome, detail in run_payloads():
            if a.k in name:
                rows.append({"case": name, "group": group_of(name), "legal": None, "outcome": outcome, "rc": None,
                             "seconds": 0, "stderr": detail})
                if outcome != "clean" or a.v:
                    print(f"{outcome:9s} {name}: {detail}", flush=True)
    by: dict = {}
    for row in rows:
        by.setdefault(row["group"], {o: 0 for o in OUTCOMES})[row["outcome"]] += 1
    print()
    for g, c in sorted(by.items()):
        print(f"  {g:32s} " + " ".join(f"{o} {n:4d}" for o, n in c.items()))
    total = {o: sum(r["outcome"] == o for r in rows) for o in OUTCOMES}
    print(f"\n{len(rows)} cases ({sum(r['legal'] is False for r in rows)} bad, {sum(r['legal'] is True for r in rows)} "
          f"legal, {sum(r['legal'] is None for r in rows)} either) in {time.monotonic() - t0:.0f} s: "
          + ", ".join(f"{o} {n}" for o, n in total.items()))
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    import shutil

    shutil.rmtree(folder, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
