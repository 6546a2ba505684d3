"""A battery of hand-made bad inputs across every verb, run through the real CLI.

Each case is a command line of ``valvectl`` with its input files (recordings,
model files of every kind, run/plant/sweep configurations, CLI arguments).
It runs in a forked child (``controller.cli.main(argv)``, the parent having
imported the heavy modules once) with a timeout, and ends in one of:

- ``clean``: exit 2 with one line on stderr (bad input said so), or exit 0
  for a case marked legal;
- ``accepted``: exit 0 on a bad input (silent acceptance);
- ``multiline``: exit 2 with more or less than one line on stderr;
- ``traceback``: an uncaught exception (any exit other than 0 and 2);
- ``hang``: still running at the timeout (killed).

``python -m tests.battery [--root CHECKOUT] [--jobs N] [--timeout S] [-k WORD] [-v]``
prints the counts per outcome and per verb, and the cases that did not end
cleanly. ``--root`` runs another checkout's code (e.g. ``git worktree add
/tmp/before COMMIT``) with the same cases: the before/after figures of the
fail-safe issue come from here. :mod:`tests.test_fuzz` runs a sample of it in
``make test`` and all of it in the slow suite.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import signal
import socket
import sys
import tempfile
import time
import traceback
from dataclasses import dataclass, field

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

#: Outcomes, in the order they are reported.
OUTCOMES = ("clean", "accepted", "multiline", "traceback", "hang")


@dataclass
class Case:
    """One command line and the files it reads.

    Attributes
    ----------
    name : str
        ``kind/what``, unique.
    argv : list of str
        ``valvectl`` arguments; ``{d}`` is the case's folder, ``{port}`` and ``{port2}`` free TCP ports.
    files : dict
        File name (in the case's folder) -> text or bytes; ``None`` makes a folder.
    legal : bool
        True when the input is legal (exit 0 expected, e.g. a CSV with a BOM).
    config : bool
        Copy the checkout's ``config/`` folder into the case's folder first.
    """

    name: str
    argv: list
    files: dict = field(default_factory=dict)
    legal: bool = False
    config: bool = False


# -- inputs -----------------------------------------------------------------------------------

def _recording(n: int = 1000, rate_hz: float = 50.0, header: str = "t_s,duty_pct,flow_lpm",
               duty=None, flow=None, t=None, eol: str = "\n") -> str:
    """A small valve-like recording: a few sweeps of duty through a play-operator hysteresis."""
    import numpy as np

    t = np.arange(n) / rate_hz if t is None else np.asarray(t, dtype=float)
    d = 40.0 + 30.0 * (0.5 + 0.5 * np.sin(2 * np.pi * 0.37 * t) * np.cos(2 * np.pi * 0.05 * t)) if duty is None \
        else np.broadcast_to(np.asarray(duty, dtype=float), t.shape)
    if flow is None:
        y = np.empty_like(d)
        s = d[0]
        for i, x in enumerate(d):  # one play operator of half-width 3 %
            s = min(max(s, x - 3.0), x + 3.0)
            y[i] = max(0.0, 4.0 * (s - 35.0))
        f = y
    else:
        f = np.broadcast_to(np.asarray(flow, dtype=float), t.shape)
    rows = [header] + [f"{a:.6g},{b:.6g},{c:.6g}" for a, b, c in zip(t, d, f)]
    return eol.join(rows) + eol


def recordings() -> dict[str, tuple[str | bytes, bool]]:
    """name -> (content, legal)."""
    good = _recording()
    lines = good.splitlines()
    head, body = lines[0], lines[1:]

    def edit(row: int, col: int, value: str) -> str:
        cells = body[row].split(",")
        cells[col] = value
        return "\n".join([head, *body[:row], ",".join(cells), *body[row + 1:]]) + "\n"

    r: dict[str, tuple[str | bytes, bool]] = {
        "good": (good, True),
        "bom_crlf": ("\ufeff" + _recording(eol="\r\n"), True),
        "crlf": (_recording(eol="\r\n"), True),
        "extra_column": (_recording(header="t_s,duty_pct,flow_lpm").replace("\n", ",x\n").replace("flow_lpm,x", "flow_lpm,note"), True),
        "empty": ("", False),
        "blank_lines_only": ("\n\n\n", False),
        "header_only": (head + "\n", False),
        "bom_only": ("\ufeff", False),
        "one_row": ("\n".join([head, body[0]]) + "\n", False),
        "two_rows": ("\n".join([head, *body[:2]]) + "\n", False),
        "three_rows": ("\n".join([head, *body[:3]]) + "\n", False),
        "constant_duty": (_recording(duty=50.0), False),
        "constant_duty_zero": (_recording(duty=0.0, flow=0.0), False),
        "two_duty_levels_few_rows": (_recording(n=6), False),
        "missing_t_s": (good.replace("t_s,", "time,", 1), False),
        "missing_duty": (good.replace("duty_pct", "duty", 1), False),
        "missing_flow": (good.replace("flow_lpm", "flow", 1), False),
        "duplicate_column": (good.replace("flow_lpm", "duty_pct", 1), False),
        "semicolons": (good.replace(",", ";"), False),
        "tabs": (good.replace(",", "\t"), False),
        "ragged_short": ("\n".join([head, *body[:5], "0.9,50", *body[6:]]) + "\n", False),
        "ragged_long": ("\n".join([head, *body[:5], body[5] + ",1,2", *body[6:]]) + "\n", False),
        "latin1": (good.encode() + "0.99,50,10,é\n".encode("latin-1"), False),
        "binary": (bytes(range(256)) * 8, False),
        "nul_bytes": (good.replace("\n", "\x00\n", 3), False),
        "cr_only": (good.replace("\n", "\r"), True),
        "time_equal": (edit(10, 0, body[9].split(",")[0]), False),
        "time_backwards": (edit(10, 0, "0"), False),
        "gap_1e9_s": (edit(200, 0, "1e9").replace("\n" + "\n".join(body[201:]), "\n" + "\n".join(
            f"{1e9 + i * 0.01:.12g},{x.split(',')[1]},{x.split(',')[2]}" for i, x in enumerate(body[201:], 1))), False),
        "rate_1e14_hz": (_recording(t=[i * 1e-14 for i in range(1000)]), False),
        "time_1e300": (_recording(t=[1e300 * (1 + i * 1e-3) for i in range(1000)]), False),
        "time_offset_1e15": (_recording(t=[1e15 + i * 0.01 for i in range(1000)]), False),
        "flow_1e308": (edit(50, 2, "1e308"), False),
        "flow_all_1e308": (_recording(flow=1e308), False),
        "flow_1e309": (edit(50, 2, "1e309"), False),
        "flow_minus_1e308": (edit(50, 2, "-1e308"), False),
        "duty_minus_1": (edit(7, 1, "-1"), False),
        "duty_101": (edit(7, 1, "101"), False),
        "duty_1e308": (edit(7, 1, "1e308"), False),
        "empty_cell": (edit(7, 2, ""), False),
        "space_cell": (edit(7, 2, "  "), False),
        "quoted_number": (edit(7, 2, '"10"'), False),
        "underscore_number": (edit(7, 2, "1_0"), False),
        "hex_number": (edit(7, 2, "0x10"), False),
        "word_infinity": (edit(7, 2, "infinity"), False),
    }
    for col, name in enumerate(("t_s", "duty_pct", "flow_lpm")):
        for word in ("abc", "nan", "inf", "-inf", "NaN"):
            r[f"{word}_in_{name}"] = (edit(20, col, word), False)
    r["huge_line"] = ("\n".join([head, *body[:5], body[5] + "," + "9" * 200_000, *body[6:]]) + "\n", False)
    r["many_columns"] = (",".join([head] + [f"c{i}" for i in range(5000)]) + "\n"
                         + "\n".join(b + "," + ",".join("1" for _ in range(5000)) for b in body[:200]) + "\n", True)
    return r


def _pi_model() -> dict:
    return {"format": "valvectl-model", "version": 1, "kind": "pi",
            "input": {"name": "duty_pct", "center": 55.0, "half_range": 20.0},
            "output": {"name": "flow_lpm", "center": 100.0, "half_range": 90.0},
            "params": {"r": [0.0, 0.25, 0.5, 0.75], "w": [0.6, 0.2, 0.1, 0.05], "offset": 0.0, "y0": None},
            "inverse": {"kind": "inverse-pi", "params": {"r": [0.0, 0.15, 0.35, 0.6],
                                                        "w": [1.6667, -0.4, -0.2, -0.1], "offset": 0.0, "x0": None}},
            "meta": {}}


def _kind_models() -> dict[str, dict]:
    """One small valid model file per kind (hand-made parameters in the files' layout)."""
    base = {k: v for k, v in _pi_model().items() if k not in ("params", "inverse", "kind")}
    n = 4
    alpha, beta = [], []
    for i in range(n):
        for j in range(i + 1):
            alpha.append(-1 + 2 * (i + 1) / n)
            beta.append(-1 + 2 * j / n)
    return {
        "pi": _pi_model(),
        "pi-asym": {**base, "kind": "pi-asym", "params": {"r": [0.0, 0.3, 0.6], "w": [0.7, 0.2, 0.1], "a": 0.2,
                                                         "p": 1.5, "offset": 0.0},
                    "inverse": {"kind": "inverse-pi-asym", "params": {"forward": {
                        "r": [0.0, 0.3, 0.6], "w": [0.7, 0.2, 0.1], "a": 0.2, "p": 1.5, "offset": 0.0}}}},
        "preisach": {**base, "kind": "preisach", "params": {"alpha": alpha, "beta": beta,
                                                           "mu": [0.1] * len(alpha), "offset": 0.0}},
        "preisach-cont": {**base, "kind": "preisach-cont",
                          "params": {"everett": [[0.1 * (i + j) for j in range(4)] for i in range(4)], "offset": 0.0}},
        "bouc-wen": {**base, "kind": "bouc-wen", "params": {"beta": 2.0, "gamma": 0.5, "n": 1.5, "a": 0.5, "b": 0.5,
                                                           "c": 0.0}},
    }


def model_files() -> dict[str, tuple[str, bool]]:
    """name -> (JSON text, legal)."""
    def dump(d):
        return json.dumps(d)

    out: dict[str, tuple[str, bool]] = {}
    for kind, m in _kind_models().items():
        out[f"{kind}/good"] = (dump(m), True)
        for key, value in m["params"].items():
            if isinstance(value, list):
                flat = value[0] if not isinstance(value[0], list) else value[0][0]
                del flat
                for label, bad in (("nan", float("nan")), ("inf", float("inf")), ("string", "x")):
                    p = json.loads(json.dumps(m))
                    target = p["params"][key]
                    if isinstance(target[0], list):
                        target[1][1] = bad
                    else:
                        target[-1] = bad
                    out[f"{kind}/{key}_{label}"] = (json.dumps(p), False)
                p = json.loads(json.dumps(m))
                p["params"][key] = p["params"][key][:-1]
                out[f"{kind}/{key}_shorter"] = (dump(p), False)
                p = json.loads(json.dumps(m))
                p["params"][key] = []
                out[f"{kind}/{key}_empty"] = (dump(p), False)
            elif isinstance(value, (int, float)):
                for label, bad in (("nan", float("nan")), ("inf", float("-inf")), ("string", "1"), ("null", None)):
                    p = json.loads(json.dumps(m))
                    p["params"][key] = bad
                    out[f"{kind}/{key}_{label}"] = (json.dumps(p), False)
        p = json.loads(json.dumps(m))
        del p["params"]
        out[f"{kind}/no_params"] = (dump(p), False)
        p = json.loads(json.dumps(m))
        p["params"]["extra"] = 1
        out[f"{kind}/unknown_param"] = (dump(p), False)
    pi = _pi_model()
    for label, edit in {
        "half_range_0": lambda d: d["input"].update(half_range=0.0),
        "half_range_negative": lambda d: d["output"].update(half_range=-5.0),
        "center_nan": lambda d: d["input"].update(center=float("nan")),
        "scale_missing": lambda d: d.pop("output"),
        "format_other": lambda d: d.update(format="other"),
        "version_2": lambda d: d.update(version=2),
        "kind_unknown": lambda d: d.update(kind="warp"),
        "kind_missing": lambda d: d.pop("kind"),
        "kind_number": lambda d: d.update(kind=3),
        "params_list": lambda d: d.update(params=[1, 2]),
        "inverse_w0_zero": lambda d: d["inverse"]["params"]["w"].__setitem__(0, 0.0),
        "inverse_nan": lambda d: d["inverse"]["params"]["w"].__setitem__(1, float("nan")),
        "inverse_kind_wrong": lambda d: d["inverse"].update(kind="preisach"),
        "inverse_shorter": lambda d: d["inverse"]["params"].update(w=[1.0]),
        "y0_wrong_length": lambda d: d["params"].update(y0=[0.0]),
        "r_descending": lambda d: d["params"].update(r=[0.75, 0.5, 0.25, 0.0]),
        "r_negative": lambda d: d["params"].update(r=[-1.0, 0.25, 0.5, 0.75]),
        "w_huge": lambda d: d["params"].update(w=[1e308, 1e308, 1e308, 1e308]),
        "meta_nan_legal": lambda d: d["meta"].update(mae=float("nan")),
    }.items():
        d = json.loads(json.dumps(pi))
        edit(d)
        out[f"pi/{label}"] = (json.dumps(d), label.endswith("_legal"))
    out["json/not_json"] = ("{", False)
    out["json/empty"] = ("", False)
    out["json/array"] = ("[]", False)
    out["json/null"] = ("null", False)
    out["json/string"] = ('"pi"', False)
    out["json/deep_array"] = ("[" * 100_000 + "]" * 100_000, False)
    out["json/deep_object_in_meta"] = (json.dumps(pi)[:-1].replace('"meta": {}', '"meta": ' + '{"a":' * 50_000 + "1"
                                                                    + "}" * 50_000) + "}", False)
    out["json/deep_in_params"] = (json.dumps(pi).replace('"w": [0.6,', '"w": [' + "[" * 5000 + "0.6" + "]" * 5000 + ","),
                                  False)
    out["json/int_400_digits"] = (json.dumps(pi).replace("0.6,", "9" * 400 + ",", 1), False)
    out["json/int_5000_digits"] = (json.dumps(pi).replace("0.6,", "9" * 5000 + ",", 1), False)
    out["json/float_1e400"] = (json.dumps(pi).replace("0.6,", "1e400,", 1), False)
    out["json/bom"] = ("\ufeff" + json.dumps(pi), True)
    out["json/hook_model"] = ('{"kind": "pi", "r": [0.1, 0.2], "w": [1.0]}', False)
    return out


def _toml_edits() -> dict[str, tuple[str, str, bool]]:
    """run.toml edits: name -> (line to find, replacement, legal)."""
    e = {}
    loop = {"rate_hz = 1000.0": ["0", "-1000.0", "nan", "inf", "1e-9", "1e14", '"fast"', "true"],
            "stale_ms = 50.0": ["0", "-1", "nan", "inf", "-inf"],
            "ref_stale_ms = 500.0": ["0", "-1", "nan"],
            "safe_duty_pct = 0.0": ["150.0", "-1.0", "nan", "inf"],
            "flow_max_lpm = 200.0": ["0", "-200.0", "nan", "1e308"],
            "status_hz = 10.0": ["0", "-1.0", "nan", "inf", "1e-12"],
            "spin_us = 300.0": ["-1.0", "nan", "1e15"],
            "rt_priority = 20": ["-1", "1000", "1.5", "true"],
            "duty_min_pct = 0.0": ["-10.0", "100.0", "nan", "150.0"],
            "duty_max_pct = 100.0": ["150.0", "0.0", "nan", "-1.0"],
            "rate_pct_per_s = 10000.0": ["0", "-1.0", "nan"],
            "tau_s = 0.02": ["-0.02", "nan", "1e300"],
            "delay_s = 0.02": ["-0.02", "nan", "1e9", "inf"],
            "lead_lag_s = 0.003": ["0", "-1.0", "nan"],
            "preview = true": ['"yes"', "1"],
            "kp = 0.2": ["nan", "-0.2", "inf", '"x"'],
            "ki = 5.0": ["nan", "1e308"],
            "tf_s = 0.003": ["0", "nan", "-1.0"],
            "q_flow_lpm = 3.0": ["nan", "-3.0"],
            "r_lpm = 0.5 ": ["0 ", "nan ", "-0.5 "],
            'id = "insp"': ['"**"', '"*"', '"$*"', '"a/b"', '""', '"a?b"', '"a#b"', '"insp/**"', "3"],
            'listen = ["tcp/127.0.0.1:7447"]': ['"tcp/127.0.0.1:7447"', "[1]", '[""]'],
            "command_timeout_ms = 100.0": ["0", "-1.0", "nan", "inf"],
            'controller = "ff+kf"': ['"warp"', '""', "3"],
            'plant = "sim"': ['"mars"'],
            'reference = "profile"': ['"nowhere"'],
            "duration_s = 20.0": ["-1.0", "nan", "inf"],
            "seed = 0 ": ["-1 ", "1.5 ", '"x" ', "99999999999999999999 "],
            'model = "valve_model.json"': ['"missing.json"', '""', "3"],
            'plant_config = "plant.toml"': ['"missing.toml"', '""'],
            'kind = "square"': ['"triangle"'],
            "peak_lpm = 60.0": ["-60.0", "nan", "1e308"],
            "breath_rate_bpm = 20.0": ["0", "nan", "1e-300"],
            "ie_ratio = 0.5": ["0", "-1"],
            "valve_dynamics = 0.02": ["-1.0", "nan", "1e9"],
            "transport_delay = 0.02": ["1e9", "nan"]}
    for find, values in loop.items():
        key = find.split(" =")[0]
        for v in values:
            e[f"{key}={v.strip()}"] = (find, find.split("=")[0] + "= " + v, False)
    e["unknown_section"] = ("[limits]", "[limitz]", False)
    e["unknown_key"] = ("rate_hz = 1000.0", "rate_hz = 1000.0\nrate = 5", False)
    e["unknown_effect"] = ("valve_dynamics = 0.02", "warp = 1", False)
    e["bad_toml"] = ("[limits]", "[limits", False)
    e["section_as_value"] = ("[limits]", "limits = 3\n[limitz_]", False)
    e["effects_string"] = ("valve_dynamics = 0.02", 'valve_dynamics = "fast"', False)
    e["profile_unknown"] = ("ie_ratio = 0.5", "ie_ratio = 0.5\nwarp = 1", False)
    e["as_is"] = ("[limits]", "[limits]", True)
    return e


def _plant_edits() -> dict[str, tuple[str, str, bool]]:
    e = {}
    for find, values in {"noise_lpm = 0.5": ["-0.5", "nan", "inf"],
                         "scale_factor = 120.0": ["-1.0", "nan"],
                         "range_lpm = [-250.0, 250.0]": ["[250.0, -250.0]", "[0.0]", "[nan, 1.0]", '"wide"'],
                         "supply_bar = 3.0": ["-5.0", "nan"],
                         "atmosphere_bar = 1.01325": ["0", "-1.0", "nan"],
                         "droop_ref_lpm = 200.0": ["0", "nan"],
                         "wander_tau_s = 30.0": ["0", "-1.0"],
                         "coil_tau_s = 180.0": ["0", "nan"],
                         "dynamics_order = 1": ["3", "1.5", '"one"'],
                         "creep_tau_s = 20.0": ["0"],
                         'model = "valve_model.json"': ['"missing.json"', "3"],
                         "dead_zone = 0.0": ["150.0", "nan", "-1.0"],
                         "saturation = 0.0": ["1e308"],
                         "transport_delay = 0.0": ["1e9", "inf"]}.items():
        key = find.split(" =")[0]
        for v in values:
            e[f"{key}={v}"] = (find, find.split("=")[0] + "= " + v, False)
    e["unknown_section"] = ("[coil]", "[coyle]", False)
    e["no_model"] = ('model = "valve_model.json"', "", False)
    e["as_is"] = ("[coil]", "[coil]", True)
    return e


_SWEEP_SMALL = """run = "run.toml"
duration_s = 0.2
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


def _sweep_edits() -> dict[str, tuple[str, str, bool]]:
    e = {}
    for find, values in {"duration_s = 0.2": ["0", "-1.0", "nan", "inf", "1e9"],
                         "seed = 0": ["-1", "1.5"],
                         'objective = "iae"': ['"warp"', '"worst_iae"'],
                         "margins_top = 1": ["-1", "1e9"],
                         "chunk_loops = 8": ["0", "-8", "1e12"],
                         "peak_lpm = 60.0": ["nan", "-60.0"],
                         'run = "run.toml"': ['"missing.toml"', '""'],
                         'controller = "pid"': ['"warp"'],
                         "sample = 2": ["0", "-1", "1000000000000", '"all"'],
                         "pid.kp = {log = [0.03, 1.0]}": ["{log = [-1.0, 1.0]}", "{log = [1.0, 0.03]}",
                                                          "{uniform = [0.0, inf]}", "{uniform = [nan, 1.0]}",
                                                          "{uniform = [-5.0, -1.0]}", "[]", '"x"', "{cube = [1, 2]}"],
                         }.items():
        key = find.split(" =")[0]
        for v in values:
            e[f"{key}={v}"] = (find, find.split("=")[0] + "= " + v, False)
    e["variant_unknown"] = ("[[variants]]", "[[variants]]\nwarp = 1", False)
    e["variant_nan"] = ("[[variants]]", "[[variants]]\nsupply_bar = nan", False)
    e["variant_negative_tau"] = ("[[variants]]", "[[variants]]\ncoil_tau_s = -5.0", False)
    e["grid_huge"] = ('sample = 2\npid.kp = {log = [0.03, 1.0]}',
                      'sample = "grid"\n' + "\n".join(f"pid.{k} = [{', '.join(str(0.01 * i) for i in range(1, 60))}]"
                                                      for k in ("kp", "ki", "kd", "tf_s", "tt_s")), False)
    e["no_candidates"] = ('[[candidates]]\ncontroller = "pid"\nsample = 2\npid.kp = {log = [0.03, 1.0]}', "", False)
    e["unknown_setting"] = ("pid.kp = {log", "pid.kq = {log", False)
    e["as_is"] = ("chunk_loops = 8", "chunk_loops = 8", True)
    return e


def cases() -> list[Case]:
    """Every case of the battery."""
    out: list[Case] = []
    recs = recordings()
    for name, (content, legal) in recs.items():
        f = {"rec.csv": content}
        out.append(Case(f"recording/{name}/fit", ["fit", "{d}/rec.csv", "--model", "pi", "-o", "{d}/m.json"], f, legal))
        out.append(Case(f"recording/{name}/fit-bouc-wen", ["fit", "{d}/rec.csv", "--model", "bouc-wen", "-o",
                                                           "{d}/m.json"], f, legal))
        out.append(Case(f"recording/{name}/compare", ["compare", "{d}/rec.csv", "--json", "{d}/c.json"], f, legal))
        out.append(Case(f"recording/{name}/diagnose", ["diagnose", "{d}/rec.csv", "--json", "{d}/d.json"], f, legal))
        out.append(Case(f"recording/{name}/simulate-protocol",
                        ["simulate", "--protocol", "{d}/rec.csv", "--duration", "1", "-o", "{d}/s.csv"], f,
                        legal or name in ("constant_duty", "constant_duty_zero", "two_duty_levels_few_rows",
                                          "three_rows", "two_rows", "missing_flow", "flow_1e308", "flow_all_1e308",
                                          "flow_minus_1e308", "one_row", "nul_bytes", "gap_1e9_s", "rate_1e14_hz",
                                          "time_1e300")
                        or name.endswith("_in_flow_lpm") or name in ("flow_1e309", "empty_cell", "space_cell",
                                                                     "quoted_number", "hex_number", "underscore_number",
                                                                     "word_infinity")))
    out.append(Case("recording/gap_1e9_s/simulate-protocol-whole", ["simulate", "--protocol", "{d}/rec.csv", "-o",
                                                                     "{d}/s.csv"], {"rec.csv": recs["gap_1e9_s"][0]}))
    out.append(Case("recording/missing_file/fit", ["fit", "{d}/nope.csv", "--model", "pi", "-o", "{d}/m.json"]))
    out.append(Case("recording/a_folder/fit", ["fit", "{d}/folder", "--model", "pi", "-o", "{d}/m.json"],
                    {"folder": None}))
    out.append(Case("recording/a_folder/compare", ["compare", "{d}/folder", "--json", "{d}/c.json"], {"folder": None}))
    out.append(Case("recording/validate_bad/compare", ["compare", "{d}/rec.csv", "--validate", "{d}/v.csv",
                                                       "--json", "{d}/c.json"],
                    {"rec.csv": recs["good"][0], "v.csv": recs["nan_in_flow_lpm"][0]}))

    good_rec = recs["good"][0]
    for name, (text, legal) in model_files().items():
        f = {"m.json": text, "rec.csv": good_rec}
        out.append(Case(f"model/{name}/diagnose", ["diagnose", "{d}/rec.csv", "--model", "{d}/m.json", "--json",
                                                   "{d}/d.json"], f, legal))
        out.append(Case(f"model/{name}/run", ["run", "--config", "{d}/config/run.toml", "--controller", "pid",
                                              "--duration", "0.2", "--listen", "tcp/127.0.0.1:{port}"],
                        {"config/valve_model.json": text}, legal, config=True))  # every kind simulates a valve
        if name.startswith(("pi/", "json/")):
            out.append(Case(f"model/{name}/run-ff", ["run", "--config", "{d}/config/run.toml", "--controller", "ff",
                                                     "--duration", "0.2", "--listen", "tcp/127.0.0.1:{port}"],
                            {"config/valve_model.json": text}, legal, config=True))
            out.append(Case(f"model/{name}/simulate", ["simulate", "--plant", "{d}/config/plant.toml", "--duration",
                                                       "1", "-o", "{d}/s.csv"],
                            {"config/valve_model.json": text}, legal, config=True))

    for name, (find, repl, legal) in _toml_edits().items():
        edit = {"config/run.toml": ("edit", find, repl)}
        out.append(Case(f"run.toml/{name}/run", ["run", "--config", "{d}/config/run.toml", "--duration", "0.2",
                                                 "--listen", "tcp/127.0.0.1:{port}"], edit, legal, config=True))
        node_legal = legal or name.startswith("model=")  # the node simulates plant_config; it reads no model
        out.append(Case(f"run.toml/{name}/valve-node", ["valve-node", "--config", "{d}/config/run.toml", "--duration",
                                                        "0.3", "--listen", "tcp/127.0.0.1:{port}", "--connect",
                                                        "tcp/127.0.0.1:{port2}"], edit, node_legal, config=True))
    for name, (find, repl, legal) in _plant_edits().items():
        out.append(Case(f"plant.toml/{name}/simulate", ["simulate", "--plant", "{d}/config/plant.toml", "--duration",
                                                        "1", "-o", "{d}/s.csv"],
                        {"config/plant.toml": ("edit", find, repl)}, legal, config=True))
    for name, (find, repl, legal) in _sweep_edits().items():
        out.append(Case(f"sweep.toml/{name}/sweep", ["sweep", "--config", "{d}/config/small.toml", "-o", "{d}/s.csv",
                                                     "--workers", "1"],
                        {"config/small.toml": ("edit", find, repl, _SWEEP_SMALL)}, legal, config=True))

    rec = {"rec.csv": good_rec}
    args = [
        ("simulate --duration nan", ["simulate", "--duration", "nan", "-o", "{d}/s.csv"], {}),
        ("simulate --duration -1", ["simulate", "--duration", "-1", "-o", "{d}/s.csv"], {}),
        ("simulate --duration inf", ["simulate", "--duration", "inf", "-o", "{d}/s.csv"], {}),
        ("simulate --duration 1e308", ["simulate", "--duration", "1e308", "-o", "{d}/s.csv"], {}),
        ("simulate --duration 0", ["simulate", "--duration", "0", "-o", "{d}/s.csv"], {}),
        ("simulate --rate 0", ["simulate", "--rate", "0", "-o", "{d}/s.csv"], {}),
        ("simulate --rate -100", ["simulate", "--rate", "-100", "-o", "{d}/s.csv"], {}),
        ("simulate --rate nan", ["simulate", "--rate", "nan", "-o", "{d}/s.csv"], {}),
        ("simulate --rate 1e14", ["simulate", "--rate", "1e14", "-o", "{d}/s.csv"], {}),
        ("simulate --rate 1e-9", ["simulate", "--rate", "1e-9", "-o", "{d}/s.csv"], {}),
        ("simulate --seed -1", ["simulate", "--seed", "-1", "--duration", "1", "-o", "{d}/s.csv"], {}),
        ("simulate --seed huge", ["simulate", "--seed", "9" * 30, "--duration", "1", "-o", "{d}/s.csv"], {}),
        ("simulate --effect warp", ["simulate", "--effect", "warp=1", "-o", "{d}/s.csv"], {}),
        ("simulate --effect nan", ["simulate", "--effect", "dead_zone=nan", "-o", "{d}/s.csv"], {}),
        ("simulate --effect huge", ["simulate", "--effect", "transport_delay=1e9", "-o", "{d}/s.csv"], {}),
        ("simulate --effect empty", ["simulate", "--effect", "=", "-o", "{d}/s.csv"], {}),
        ("simulate --protocol warp", ["simulate", "--protocol", "warp", "-o", "{d}/s.csv"], {}),
        ("simulate --plant missing", ["simulate", "--plant", "{d}/nope.toml", "-o", "{d}/s.csv"], {}),
        ("simulate --plant folder", ["simulate", "--plant", "{d}/folder", "-o", "{d}/s.csv"], {"folder": None}),
        ("simulate -o missing folder", ["simulate", "--duration", "1", "-o", "{d}/no/such/s.csv"], {}),
        ("simulate -o a folder", ["simulate", "--duration", "1", "-o", "{d}/folder"], {"folder": None}),
        ("fit -o missing folder", ["fit", "{d}/rec.csv", "--model", "pi", "-o", "{d}/no/m.json"], rec),
        ("fit -o a folder", ["fit", "{d}/rec.csv", "--model", "pi", "-o", "{d}/folder"], {**rec, "folder": None}),
        ("fit --json missing folder", ["fit", "{d}/rec.csv", "--model", "pi", "-o", "{d}/m.json", "--json",
                                       "{d}/no/f.json"], rec),
        ("fit --json a folder", ["fit", "{d}/rec.csv", "--model", "pi", "-o", "{d}/m.json", "--json", "{d}/folder"],
         {**rec, "folder": None}),
        ("fit --model warp", ["fit", "{d}/rec.csv", "--model", "warp", "-o", "{d}/m.json"], rec),
        ("fit --n 0", ["fit", "{d}/rec.csv", "--model", "pi", "--n", "0", "-o", "{d}/m.json"], rec),
        ("fit --n -5", ["fit", "{d}/rec.csv", "--model", "pi", "--n", "-5", "-o", "{d}/m.json"], rec),
        ("fit --n huge", ["fit", "{d}/rec.csv", "--model", "pi", "--n", "1000000000", "-o", "{d}/m.json"], rec),
        ("fit preisach --n huge", ["fit", "{d}/rec.csv", "--model", "preisach", "--n", "100000", "-o",
                                   "{d}/m.json"], rec),
        ("fit preisach-cont --n huge", ["fit", "{d}/rec.csv", "--model", "preisach-cont", "--n", "100000", "-o",
                                        "{d}/m.json"], rec),
        ("fit --n x", ["fit", "{d}/rec.csv", "--model", "pi", "--n", "x", "-o", "{d}/m.json"], rec),
        ("compare --json missing folder", ["compare", "{d}/rec.csv", "--json", "{d}/no/c.json"], rec),
        ("compare --json a folder", ["compare", "{d}/rec.csv", "--json", "{d}/folder"], {**rec, "folder": None}),
        ("compare --plot missing folder", ["compare", "{d}/rec.csv", "--json", "{d}/c.json", "--plot",
                                           "{d}/no/p.png"], rec),
        ("compare --validate missing", ["compare", "{d}/rec.csv", "--validate", "{d}/nope.csv", "--json",
                                        "{d}/c.json"], rec),
        ("diagnose --json missing folder", ["diagnose", "{d}/rec.csv", "--json", "{d}/no/d.json"], rec),
        ("diagnose --json a folder", ["diagnose", "{d}/rec.csv", "--json", "{d}/folder"], {**rec, "folder": None}),
        ("diagnose --predictions missing folder", ["diagnose", "{d}/rec.csv", "--json", "{d}/d.json",
                                                   "--predictions", "{d}/no/p.csv"], rec),
        ("diagnose --report a file", ["diagnose", "{d}/rec.csv", "--json", "{d}/d.json", "--report", "{d}/rec.csv"],
         rec),
        ("diagnose --model missing", ["diagnose", "{d}/rec.csv", "--model", "{d}/nope.json", "--json", "{d}/d.json"],
         rec),
        ("run --duration nan", ["run", "--duration", "nan", "--listen", "tcp/127.0.0.1:{port}"], {}),
        ("run --duration -1", ["run", "--duration", "-1", "--listen", "tcp/127.0.0.1:{port}"], {}),
        ("run --duration inf", ["run", "--duration", "inf", "--listen", "tcp/127.0.0.1:{port}"], {}),
        ("run --duration -inf", ["run", "--duration", "-inf", "--listen", "tcp/127.0.0.1:{port}"], {}),
        ("run --config missing", ["run", "--config", "{d}/nope.toml", "--duration", "0.2"], {}),
        ("run --config folder", ["run", "--config", "{d}/folder", "--duration", "0.2"], {"folder": None}),
        ("run --json missing folder", ["run", "--duration", "0.2", "--json", "{d}/no/s.json", "--listen",
                                       "tcp/127.0.0.1:{port}"], {}),
        ("run --record missing folder", ["run", "--duration", "0.2", "--record", "{d}/no/r.csv", "--listen",
                                         "tcp/127.0.0.1:{port}"], {}),
        ("run --record a folder", ["run", "--duration", "0.2", "--record", "{d}/folder", "--listen",
                                   "tcp/127.0.0.1:{port}"], {"folder": None}),
        ("run --plot missing folder", ["run", "--duration", "0.2", "--plot", "{d}/no/r.png", "--listen",
                                       "tcp/127.0.0.1:{port}"], {}),
        ("run --controller warp", ["run", "--controller", "warp", "--duration", "0.2"], {}),
        ("run --listen garbage", ["run", "--plant", "zenoh", "--duration", "0.2", "--listen", "garbage"], {}),
        ("valve-node --duration nan", ["valve-node", "--duration", "nan", "--listen", "tcp/127.0.0.1:{port}",
                                       "--connect", "tcp/127.0.0.1:{port2}"], {}),
        ("valve-node --duration -1", ["valve-node", "--duration", "-1", "--listen", "tcp/127.0.0.1:{port}",
                                      "--connect", "tcp/127.0.0.1:{port2}"], {}),
        ("valve-node --duration inf", ["valve-node", "--duration", "inf", "--listen", "tcp/127.0.0.1:{port}",
                                       "--connect", "tcp/127.0.0.1:{port2}"], {}),
        ("valve-node --listen garbage", ["valve-node", "--duration", "0.3", "--listen", "garbage"], {}),
        ("valve-node --config missing", ["valve-node", "--config", "{d}/nope.toml", "--duration", "0.3"], {}),
        ("sweep --workers 0", ["sweep", "-o", "{d}/s.csv", "--workers", "0"], {}),
        ("sweep --workers -1", ["sweep", "-o", "{d}/s.csv", "--workers", "-1"], {}),
        ("sweep --config missing", ["sweep", "--config", "{d}/nope.toml", "-o", "{d}/s.csv"], {}),
        ("sweep -o missing folder", ["sweep", "--config", "{d}/config/small.toml", "-o", "{d}/no/s.csv",
                                     "--workers", "1"], {"config/small.toml": _SWEEP_SMALL}),
        ("sweep -o a folder", ["sweep", "--config", "{d}/config/small.toml", "-o", "{d}/folder", "--workers", "1"],
         {"config/small.toml": _SWEEP_SMALL, "folder": None}),
        ("sweep --best-config missing folder", ["sweep", "--config", "{d}/config/small.toml", "-o", "{d}/s.csv",
                                                "--workers", "1", "--best-config", "{d}/no/b.toml"],
         {"config/small.toml": _SWEEP_SMALL}),
        ("sweep --json a folder", ["sweep", "--config", "{d}/config/small.toml", "-o", "{d}/s.csv",
                                   "--workers", "1", "--json", "{d}/folder"],
         {"config/small.toml": _SWEEP_SMALL, "folder": None}),
        ("run --plot unknown suffix", ["run", "--duration", "0.2", "--plot", "{d}/r.xyz"], {}),
        ("compare --plot unknown suffix", ["compare", "{d}/rec.csv", "--json", "{d}/c.json", "--plot", "{d}/p.xyz"],
         rec),
        ("sweep --plot unknown suffix", ["sweep", "--config", "{d}/config/small.toml", "-o", "{d}/s.csv",
                                         "--workers", "1", "--plot", "{d}/p"], {"config/small.toml": _SWEEP_SMALL}),
        ("run --certs missing", ["run", "--plant", "zenoh", "--duration", "0.2", "--certs", "{d}/nope",
                                 "--listen", "tcp/127.0.0.1:{port}"], {}),
        ("run --certs empty folder", ["run", "--plant", "zenoh", "--duration", "0.2", "--certs", "{d}/folder",
                                      "--listen", "tcp/127.0.0.1:{port}"], {"folder": None}),
        ("run --certs garbage files", ["run", "--plant", "zenoh", "--duration", "0.2", "--certs", "{d}/c",
                                       "--listen", "tcp/127.0.0.1:{port}"],
         {"c/ca.pem": "garbage", "c/controller.pem": "garbage", "c/controller.key": "garbage"}),
        ("valve-node --certs missing", ["valve-node", "--duration", "0.3", "--certs", "{d}/nope",
                                        "--connect", "tcp/127.0.0.1:{port}"], {}),
        ("certs DIR a file", ["certs", "{d}/rec.csv"], rec),
        ("certs --days 0", ["certs", "{d}/c", "--days", "0"], {}),
        ("certs --days -1", ["certs", "{d}/c", "--days", "-1"], {}),
        ("certs --days huge", ["certs", "{d}/c", "--days", "9" * 12], {}),
        ("certs --host empty", ["certs", "{d}/c", "--host", ""], {}),
        ("certs --host spaces", ["certs", "{d}/c", "--host", "not a host"], {}),
        ("certs --site empty", ["certs", "{d}/c", "--site", ""], {}),
        ("monitor --duration nan", ["monitor", "--duration", "nan", "--connect", "tcp/127.0.0.1:{port}"], {}),
        ("monitor --duration -1", ["monitor", "--duration", "-1", "--connect", "tcp/127.0.0.1:{port}"], {}),
        ("monitor --record missing folder", ["monitor", "--duration", "0.3", "--record", "{d}/no/m.csv",
                                             "--connect", "tcp/127.0.0.1:{port}"], {}),
        ("monitor --record a folder", ["monitor", "--duration", "0.3", "--record", "{d}/folder",
                                       "--connect", "tcp/127.0.0.1:{port}"], {"folder": None}),
        ("monitor --connect garbage", ["monitor", "--duration", "0.3", "--connect", "garbage"], {}),
        ("monitor --certs missing", ["monitor", "--duration", "0.3", "--certs", "{d}/nope",
                                     "--connect", "tcp/127.0.0.1:{port}"], {}),
        ("identify --duration nan", ["identify", "--duration", "nan", "-o", "{d}/id",
                                     "--listen", "tcp/127.0.0.1:{port}"], {}),
        ("identify --duration -1", ["identify", "--duration", "-1", "-o", "{d}/id",
                                    "--listen", "tcp/127.0.0.1:{port}"], {}),
        ("identify -o a file", ["identify", "--duration", "1", "-o", "{d}/rec.csv",
                                "--listen", "tcp/127.0.0.1:{port}"], rec),
        ("identify --listen garbage", ["identify", "--duration", "1", "-o", "{d}/id", "--listen", "garbage"], {}),
        ("identify --certs missing", ["identify", "--duration", "1", "-o", "{d}/id", "--certs", "{d}/nope",
                                      "--listen", "tcp/127.0.0.1:{port}"], {}),
        ("identify --config missing", ["identify", "--config", "{d}/nope.toml", "-o", "{d}/id"], {}),
        ("no verb", [], {}),
        ("unknown verb", ["warp"], {}),
        ("fit no args", ["fit"], {}),
    ]
    for name, argv, files in args:
        config = any(a.startswith("{d}/config") for a in argv)
        out.append(Case(f"args/{name}", argv, files, name.endswith("--duration 0") and False, config=config))
    return out


# -- running ----------------------------------------------------------------------------------

def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _materialize(case: Case, folder: str, root: str) -> list[str]:
    """Write the case's files into ``folder``; its argv with the placeholders filled in."""
    if case.config:
        shutil.copytree(os.path.join(root, "config"), os.path.join(folder, "config"))
    for name, content in case.files.items():
        path = os.path.join(folder, name)
        os.makedirs(os.path.dirname(path), exist_ok=True)
        if content is None:
            os.makedirs(path, exist_ok=True)
        elif isinstance(content, tuple):  # ("edit", find, replace[, base text])
            base = content[3] if len(content) > 3 else open(path, encoding="utf-8").read()
            find = content[1]
            if find not in base and "=" in find:  # the shipped value changed: find the key's line instead
                m = re.search(rf"^\s*{re.escape(find.split('=')[0].strip())}\s*=[^\n#]*", base, re.M)
                find = m.group(0) if m else find
            if find not in base:
                raise KeyError(f"{case.name}: {content[1]!r} not in {name}")
            with open(path, "w", encoding="utf-8") as fh:
                fh.write(base.replace(find, content[2], 1))
        else:
            with open(path, "wb") as fh:
                fh.write(content if isinstance(content, bytes) else content.encode("utf-8"))
    subs = {"{d}": folder, "{port}": str(_free_port()), "{port2}": str(_free_port())}
    out = []
    for a in case.argv:
        for k, v in subs.items():
            a = a.replace(k, v)
        out.append(a)
    return out


def _child(argv: list[str], err_path: str, root: str, timeout_s: float) -> None:
    """In the forked child: run the CLI, exit with its code (1 and a traceback on an uncaught exception).

    Just before ``timeout_s`` every thread's stack goes to the case's stderr: a hang says where it hung.
    """
    import faulthandler

    os.chdir(root)
    fd = os.open(err_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, 1)
    os.dup2(fd, 2)
    sys.stdout = open(1, "w", closefd=False)
    sys.stderr = open(2, "w", closefd=False)
    faulthandler.dump_traceback_later(max(timeout_s - 1.0, 0.5), file=sys.stderr)
    code = 1
    try:
        from controller.cli import main

        code = main(argv)
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except BaseException:  # the outcome under test: an uncaught exception
        traceback.print_exc()
        code = 1
    sys.stderr.flush()
    sys.stdout.flush()
    os._exit(code)


@dataclass
class Result:
    case: Case
    outcome: str
    rc: int | None
    stderr: str
    seconds: float


def classify(case: Case, rc: int | None, stderr: str) -> str:
    """The outcome of one case (see the module docstring)."""
    if rc is None:
        return "hang"
    if "Traceback (most recent call last)" in stderr or rc not in (0, 2):
        return "traceback"
    if rc == 0:
        return "clean" if case.legal else "accepted"
    # exit 2: bad input said so in one line (a legal input may still be refused, e.g. too short to diagnose)
    return "clean" if len(stderr.strip().splitlines()) == 1 else "multiline"


def _start(case: Case, root: str, workdir: str, timeout_s: float) -> tuple[int, str, float]:
    """Fork a child running one case; (pid, its folder, start time)."""
    folder = tempfile.mkdtemp(dir=workdir)
    argv = _materialize(case, folder, root)
    start = time.monotonic()
    pid = os.fork()
    if pid == 0:
        try:
            os.setpgid(0, 0)
            _child(argv, os.path.join(folder, ".stderr"), root, timeout_s)
        finally:
            os._exit(1)
    return pid, folder, start


def _finish(case: Case, pid: int, folder: str, start: float, rc: int | None) -> Result:
    """Collect one case (``rc`` None: it hung and is killed), clean its folder and leftover processes."""
    try:
        os.killpg(pid, signal.SIGKILL)  # a hung case, or leftovers (sweep workers) of a finished one
    except (ProcessLookupError, PermissionError):
        pass
    if rc is None:
        os.waitpid(pid, 0)
    try:
        with open(os.path.join(folder, ".stderr"), encoding="utf-8", errors="replace") as fh:
            text = fh.read()
    except FileNotFoundError:
        text = ""
    shutil.rmtree(folder, ignore_errors=True)
    return Result(case, classify(case, rc, text), rc, text, time.monotonic() - start)


def run_battery(selected: list[Case], root: str, timeout_s: float, jobs: int, progress=None) -> list[Result]:
    """Run cases, at most ``jobs`` children at a time, each killed at ``timeout_s``."""
    workdir = tempfile.mkdtemp(prefix="battery-")
    pending = list(selected)
    running: dict[int, tuple] = {}
    results = []
    try:
        while pending or running:
            while pending and len(running) < jobs:
                case = pending.pop(0)
                pid, folder, start = _start(case, root, workdir, timeout_s)
                running[pid] = (case, folder, start)
            time.sleep(0.01)
            for pid, (case, folder, start) in list(running.items()):
                done, status = os.waitpid(pid, os.WNOHANG)
                if done or time.monotonic() - start > timeout_s:
                    del running[pid]
                    r = _finish(case, pid, folder, start, os.waitstatus_to_exitcode(status) if done else None)
                    results.append(r)
                    if progress:
                        progress(r)
        return results
    finally:
        for pid in running:
            try:
                os.killpg(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        shutil.rmtree(workdir, ignore_errors=True)


def preload(root: str) -> None:
    """Import and compile (numba) what the verbs use, once, before forking: each child then starts at once.

    The warm-up runs legal commands of every verb but ``sweep`` (its worker
    processes stay out of the parent) in this process, output discarded.
    """
    import contextlib
    import io

    from controller.cli import main

    folder = tempfile.mkdtemp(prefix="battery-warm-")
    try:
        rec = os.path.join(folder, "rec.csv")
        with open(rec, "w") as fh:
            fh.write(_recording())
        runs = [["fit", rec, "--model", k, "-o", os.path.join(folder, f"{k}.json")]
                for k in ("pi", "pi-asym", "preisach", "preisach-cont", "bouc-wen")]
        runs += [["compare", rec, "--json", os.path.join(folder, "c.json")],
                 ["diagnose", rec, "--json", os.path.join(folder, "d.json")],
                 ["simulate", "--duration", "1", "-o", os.path.join(folder, "s.csv")]]
        runs += [["run", "--controller", w, "--duration", "0.05", "--config", os.path.join(root, "config", "run.toml")]
                 for w in ("ff", "pid", "ff+pid", "ff+kf")]
        for argv in runs:
            with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
                try:
                    main(argv)
                except BaseException:  # noqa: BLE001 - a warm-up only; the cases themselves are judged
                    pass
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def report(results: list[Result], group, json_path: str | None) -> None:
    """Counts per outcome for each ``group(case name)``; every case's outcome to ``json_path`` if given."""
    by: dict = {}
    for r in results:
        by.setdefault(group(r.case.name), {o: 0 for o in OUTCOMES})[r.outcome] += 1
    for name, c in sorted(by.items()):
        print(f"  {name:24s} " + " ".join(f"{o} {n:4d}" for o, n in c.items()))
    if json_path:
        with open(json_path, "w") as fh:
            json.dump([{"case": r.case.name, "outcome": r.outcome, "rc": r.rc, "stderr": r.stderr[-500:]}
                       for r in results], fh, indent=1)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", default=os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                    help="checkout whose code and config/ run the cases (default: this one)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--timeout", type=float, default=60.0, help="seconds per case before it counts as a hang")
    ap.add_argument("-k", default="", help="only cases whose name contains this")
    ap.add_argument("-v", action="store_true", help="print every case")
    ap.add_argument("--json", default=None, help="write every case's outcome here")
    a = ap.parse_args(argv)
    root = os.path.abspath(a.root)
    sys.path.insert(0, root)
    os.chdir(root)
    selected = [c for c in cases() if a.k in c.name]
    preload(root)

    def progress(r: Result) -> None:
        if a.v or r.outcome != "clean":
            last = (r.stderr.strip().splitlines() or [""])[-1][:150]
            print(f"{r.outcome:9s} rc={r.rc} {r.seconds:5.1f}s {r.case.name}: {last}", flush=True)

    results = run_battery(selected, root, a.timeout, a.jobs, progress)
    counts = {o: sum(r.outcome == o for r in results) for o in OUTCOMES}
    print(f"\n{len(results)} cases ({sum(not r.case.legal for r in results)} bad inputs, "
          f"{sum(r.case.legal for r in results)} legal) on {root}: "
          + ", ".join(f"{o} {n}" for o, n in counts.items()))
    report(results, lambda name: name.rsplit("/", 1)[-1] if not name.startswith("args/") else
           name.split("/", 1)[1].split()[0], a.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
