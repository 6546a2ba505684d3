"""A second battery of bad inputs, made by mutating the shipped files rather than by hand.

:mod:`tests.battery` lists hand-made cases and :mod:`tests.test_fuzz` draws
hypothesis strategies over a few shapes; this module walks what the checkout
ships instead and breaks every part of it mechanically:

- every numeric value of every TOML configuration (``config/**/*.toml``) and
  every model file (``config/**/*.json``): huge (±1e308), negative, NaN,
  infinite, and its type swapped (string, boolean, array, table, null);
- every table of those files: a key of the wrong kind (a number, an empty
  key) and a table where a value belongs, or a list where a table belongs;
- every column of a recording: huge, negative, NaN, infinite, subnormal,
  malformed numbers and empty cells in one row, and the whole column huge;
- every file truncated mid-way and re-encoded (UTF-16, UTF-32, Latin-1, a
  NUL byte, CR-only lines);
- every numeric option of every verb, read from the parser itself: huge,
  negative, NaN, infinite, 400 digits, malformed.

Each case runs through :func:`tests.battery.run_battery` (a forked child, a
timeout) and is judged the same way: exit 2 with one line, or exit 0.
Whether a value is legal is not known here (a negative ``offset`` is, a
negative ``rate_hz`` is not), so an exit 0 is reported as ``accepted`` for a
person to judge; tracebacks, several lines and hangs are failures whatever
the value. ``python -m tests.mutations [--jobs N] [--timeout S] [-k WORD]
[--sample N] [--seed S]`` prints the counts and every case that did not end cleanly.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import random
import re
import sys

from tests.battery import OUTCOMES, Case, _recording, preload, report, run_battery

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

#: TOML replacements of a number: (label, text).
TOML_NUMBERS = (("huge", "1e308"), ("neg_huge", "-1e308"), ("negative", "-1"), ("nan", "nan"), ("inf", "inf"),
                ("string", '"1"'), ("bool", "true"), ("array", "[1.0]"), ("table", "{ v = 1 }"),
                ("int_overflow", "99999999999999999999999"))
#: TOML replacements of a string or boolean value.
TOML_OTHERS = (("number", "1"), ("array", "[]"), ("table", "{}"))
#: JSON replacements of a number.
JSON_NUMBERS = (("huge", 1e308), ("neg_huge", -1e308), ("negative", -1.0), ("nan", math.nan), ("inf", math.inf),
                ("string", "1"), ("bool", True), ("null", None), ("list", [1.0]), ("dict", {"v": 1}))
#: Recording cells.
CELLS = (("huge", "1e308"), ("neg_huge", "-1e308"), ("negative", "-1"), ("nan", "nan"), ("inf", "inf"),
         ("subnormal", "1e-320"), ("empty", ""), ("exponent_only", "1e"), ("comma", "1,5"), ("fullwidth", "１"),
         ("digits_400", "9" * 400), ("plus_minus", "+-1"))
#: Option values.
OPTIONS = (("huge", "1e308"), ("neg_huge", "-1e308"), ("negative", "-1"), ("nan", "nan"), ("inf", "inf"),
           ("digits_400", "9" * 400), ("malformed", "1e"), ("empty", ""))

_NUMBER = r"[-+]?(?:\d[\d_]*(?:\.\d*)?(?:[eE][-+]?\d+)?|nan|inf)"
_TOML_LINE = re.compile(rf"^(\s*[\w.\"-]+\s*=\s*)({_NUMBER}|\"[^\"\n]*\"|true|false|\[[^\]\n]*\])(.*)$", re.M)


def _files(ext: str) -> list[str]:
    """The checkout's config files of one extension, relative to config/."""
    out = []
    for d, _, names in os.walk(os.path.join(ROOT, "config")):
        out += [os.path.relpath(os.path.join(d, n), os.path.join(ROOT, "config")) for n in names if n.endswith(ext)
                and not n.startswith(".")]
    return sorted(out)


def toml_mutants(text: str) -> dict[str, str]:
    """label -> mutated text: every value line's value replaced (numbers in arrays: the first element)."""
    out = {}
    section = ""
    for m in _TOML_LINE.finditer(text):
        head = text[: m.start()]
        sec = re.findall(r"^\s*\[+([^\]\n]+)\]+", head, re.M)
        section = sec[-1] if sec else ""
        key = f"{section}.{m.group(1).split('=')[0].strip()}".lstrip(".")
        value = m.group(2)
        if value.startswith("["):  # an array: its first number
            inner = re.match(rf"\[\s*({_NUMBER})", value)
            if not inner:
                continue
            subs = [(f"{key}[0]={lab}", "[" + v + value[inner.end(1):]) for lab, v in TOML_NUMBERS]
        elif re.fullmatch(_NUMBER, value):
            subs = [(f"{key}={lab}", v) for lab, v in TOML_NUMBERS]
        else:
            subs = [(f"{key}={lab}", v) for lab, v in TOML_OTHERS]
        for label, v in subs:
            out[label] = text[: m.start(2)] + v + text[m.end(2):]
    for m in re.finditer(r"^\s*\[+([^\]\n]+)\]+\s*$", text, re.M):  # wrong key kinds in every table
        name = m.group(1)
        out[f"[{name}] numeric key"] = text[: m.end()] + "\n1 = 2" + text[m.end():]
        out[f"[{name}] empty key"] = text[: m.end()] + '\n"" = 2' + text[m.end():]
        out[f"[{name}] as a number"] = text[: m.start()] + f"\n{name.split('.')[-1]} = 3\n[_after_{name}]" \
            + text[m.end():] if not m.group(0).lstrip().startswith("[[") else out.get("", "")
    out.pop("", None)
    return out


def _paths(obj, prefix=()):
    """Paths to every number (lists: their first and last element) and every container of a JSON document."""
    if isinstance(obj, dict):
        yield prefix, obj
        for k, v in obj.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(obj, list):
        yield prefix, obj
        for i in sorted({0, len(obj) - 1}) if obj else ():
            yield from _paths(obj[i], prefix + (i,))
    elif isinstance(obj, (int, float)) and not isinstance(obj, bool):
        yield prefix, obj


def _set(doc, path, value):
    d = json.loads(json.dumps(doc))
    target = d
    for p in path[:-1]:
        target = target[p]
    target[path[-1]] = value
    return d


def json_mutants(text: str) -> dict[str, str]:
    """label -> mutated JSON text: every number replaced, every table given a wrong key or made a list."""
    doc = json.loads(text)
    out = {}
    for path, v in _paths(doc):
        name = ".".join(map(str, path)) or "(top)"
        if isinstance(v, dict):
            if path:
                out[f"{name} as a list"] = json.dumps(_set(doc, path, list(v.items())))
            d = json.loads(json.dumps(doc))
            t = d
            for p in path:
                t = t[p]
            t["1"] = 1
            out[f"{name} numeric key"] = json.dumps(d)
            if v:  # its first key renamed to an empty one
                first = next(iter(v))
                t.pop("1")
                t[""] = t.pop(first)
                out[f"{name} first key empty"] = json.dumps(d)
        elif isinstance(v, list):
            if path:
                out[f"{name} as a table"] = json.dumps(_set(doc, path, {str(i): x for i, x in enumerate(v)}))
                out[f"{name} empty"] = json.dumps(_set(doc, path, []))
        else:
            for label, new in JSON_NUMBERS:
                out[f"{name}={label}"] = json.dumps(_set(doc, path, new))
    return out


def damaged(data: bytes) -> dict[str, bytes]:
    """label -> the file truncated or re-encoded."""
    text = data.decode("utf-8")
    out = {f"truncated_{p}": data[: len(data) * p // 100] for p in (1, 33, 66, 99)}
    out["truncated_mid_line"] = data[: data.rfind(b"\n", 0, len(data) // 2) + 4]
    out["utf16"] = text.encode("utf-16")
    out["utf16le_no_bom"] = text.encode("utf-16-le")
    out["utf32"] = text.encode("utf-32")
    out["latin1"] = (text + "\n# é\n").encode("latin-1", errors="replace")
    out["nul_byte"] = data[: len(data) // 2] + b"\x00" + data[len(data) // 2:]
    out["cr_only"] = data.replace(b"\n", b"\r")
    return out


def recording_mutants() -> dict[str, bytes]:
    """label -> a recording broken in one column, one way, or damaged as a whole."""
    good = _recording()
    lines = good.splitlines()
    head, body = lines[0], lines[1:]
    out: dict[str, bytes] = {}
    for col, name in enumerate(head.split(",")):
        for label, cell in CELLS:
            rows = list(body)
            cells = rows[500].split(",")
            cells[col] = cell
            rows[500] = ",".join(cells)
            out[f"{name}={label}"] = ("\n".join([head, *rows]) + "\n").encode()
        for label, cell in (("all_huge", "1e308"), ("all_negative", "-5"), ("all_subnormal", "1e-320")):
            rows = [",".join(cell if i == col else c for i, c in enumerate(r.split(","))) for r in body]
            out[f"{name}={label}"] = ("\n".join([head, *rows]) + "\n").encode()
    swapped = head.split(",")
    out["columns_swapped"] = ("\n".join([",".join(reversed(swapped)), *body]) + "\n").encode()
    out["header_numeric"] = ("\n".join(["1,2,3", *body]) + "\n").encode()
    for label, data in damaged(good.encode()).items():
        out[label] = data
    return out


#: Per verb: the smallest legal command line around a mutated input (placeholders of tests.battery).
REC = {"fit": ["fit", "{d}/rec.csv", "--model", "pi", "-o", "{d}/m.json"],
       "compare": ["compare", "{d}/rec.csv", "--json", "{d}/c.json"],
       "diagnose": ["diagnose", "{d}/rec.csv", "--json", "{d}/d.json"],
       "simulate-protocol": ["simulate", "--protocol", "{d}/rec.csv", "--duration", "1", "-o", "{d}/s.csv"]}
BASE = {"fit": REC["fit"], "compare": REC["compare"], "diagnose": REC["diagnose"],
        "simulate": ["simulate", "--duration", "1", "-o", "{d}/s.csv"],
        "run": ["run", "--duration", "0.2", "--listen", "tcp/127.0.0.1:{port}"],
        "valve-node": ["valve-node", "--duration", "0.3", "--listen", "tcp/127.0.0.1:{port}", "--connect",
                       "tcp/127.0.0.1:{port2}"],
        "sweep": ["sweep", "--config", "{d}/config/small.toml", "-o", "{d}/s.csv", "--workers", "1"],
        "certs": ["certs", "{d}/certs"],
        "monitor": ["monitor", "--connect", "tcp/127.0.0.1:{port}", "--duration", "0.3"],
        "identify": ["identify", "--listen", "tcp/127.0.0.1:{port}", "--duration", "1", "-o", "{d}/out"]}


#: Verbs that run until stopped when no duration is given.
UNTIL_STOPPED = ("valve-node", "monitor")


def _verbs_of_toml(rel: str) -> list[tuple[str, list[str]]]:
    """The verbs that read a configuration file of this name, each with its command line."""
    name = os.path.basename(rel)
    cfg = "{d}/config/" + rel
    if name == "run.toml":
        return [("run", ["run", "--config", cfg, "--duration", "0.2", "--listen", "tcp/127.0.0.1:{port}"]),
                ("valve-node", ["valve-node", "--config", cfg, "--duration", "0.3", "--listen",
                                "tcp/127.0.0.1:{port}", "--connect", "tcp/127.0.0.1:{port2}"])]
    if name == "plant.toml":
        return [("simulate", ["simulate", "--plant", cfg, "--duration", "1", "-o", "{d}/s.csv"])]
    return [("sweep", ["sweep", "--config", cfg, "-o", "{d}/s.csv", "--workers", "1"])]


def _small_sweep(text: str) -> str:
    """A sweep configuration cut down to a run of a few candidates (legal mutants must end fast)."""
    text = re.sub(r"(?m)^(duration_s\s*=\s*)[^\n#]*", r"\g<1>0.2", text)
    return re.sub(r"(?m)^(sample\s*=\s*)\d+", r"\g<1>2", text)


def numeric_options() -> list[tuple[str, str]]:
    """(verb, option) of every option the parser converts to a number."""
    from controller.cli import build_parser

    out = []
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    for verb, p in sub.choices.items():
        for a in p._actions:
            if a.option_strings and a.type in (int, float) or (a.option_strings and callable(a.type)
                                                                and getattr(a.type, "__name__", "") in
                                                                ("positive", "finite", "_positive", "_finite")):
                out.append((verb, max(a.option_strings, key=len)))
    return out


def cases(only: str = "") -> list[Case]:
    """Every case, or those whose name starts with ``only`` (only their file's mutants are made)."""
    out: list[Case] = []
    rec = _recording()

    def wanted(prefix: str) -> bool:
        return prefix.startswith(only) or only.startswith(prefix)

    for rel in _files(".toml"):
        if not wanted(f"toml/{rel}/"):
            continue
        with open(os.path.join(ROOT, "config", rel), encoding="utf-8") as fh:
            text = fh.read()
        verbs = _verbs_of_toml(rel)
        if verbs[0][0] == "sweep":
            text = _small_sweep(text)
        for label, content in {**toml_mutants(text), **damaged(text.encode())}.items():
            for verb, argv in verbs:
                out.append(Case(f"toml/{rel}/{label}/{verb}", argv, {f"config/{rel}": content}, config=True))
    for rel in _files(".json"):
        if not wanted(f"json/{rel}/"):
            continue
        with open(os.path.join(ROOT, "config", rel), encoding="utf-8") as fh:
            text = fh.read()
        try:
            json.loads(text)
        except ValueError:
            continue
        variants = {**json_mutants(text), **damaged(text.encode())}
        for label, content in variants.items():
            # the model a run's feedforward inverts (its run.toml names it valve_model.json in config/)
            out.append(Case(f"json/{rel}/{label}/run", ["run", "--config", "{d}/config/run.toml", "--controller", "ff",
                                                        "--duration", "0.2", "--listen", "tcp/127.0.0.1:{port}"],
                            {"config/valve_model.json": content}, config=True))
            out.append(Case(f"json/{rel}/{label}/diagnose", ["diagnose", "{d}/rec.csv", "--model", "{d}/m.json",
                                                             "--json", "{d}/d.json"],
                            {"m.json": content, "rec.csv": rec}))
    for label, content in (recording_mutants() if wanted("csv/") else {}).items():
        for verb, argv in REC.items():
            out.append(Case(f"csv/{label}/{verb}", argv, {"rec.csv": content}))
    good = {"rec.csv": rec}
    small = {"config/small.toml": _small_sweep(open(os.path.join(ROOT, "config", "sweep.toml")).read())}
    for verb, opt in (numeric_options() if wanted("option/") else []):
        base = BASE.get(verb)
        if base is None:
            continue
        for label, value in OPTIONS:
            if verb in UNTIL_STOPPED and opt == "--duration" and label == "huge":
                continue  # legal: a node or a monitor runs until stopped anyway; 1e308 s is that
            files = good if verb in REC else small if verb == "sweep" else {}
            out.append(Case(f"option/{verb} {opt}={label}/{verb}", [*base, f"{opt}={value}"], files,
                            config=verb == "sweep"))
    out = [c for c in out if c.name.startswith(only)]
    names = [c.name for c in out]
    assert len(names) == len(set(names)), "case names must be unique"
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--timeout", type=float, default=60.0)
    ap.add_argument("-k", default="")
    ap.add_argument("--sample", type=int, default=0, help="a random sample of this many cases")
    ap.add_argument("--seed", type=int, default=0, help="of the sample")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    os.chdir(ROOT)
    selected = [c for c in cases() if a.k in c.name]
    if a.sample:
        selected = random.Random(a.seed).sample(selected, min(a.sample, len(selected)))
    print(f"{len(selected)} cases", flush=True)
    preload(ROOT)

    def progress(r) -> None:
        if r.outcome != "clean":
            last = (r.stderr.strip().splitlines() or [""])[-1][:160]
            print(f"{r.outcome:9s} rc={r.rc} {r.seconds:5.1f}s {r.case.name}: {last}", flush=True)

    results = run_battery(selected, ROOT, a.timeout, a.jobs, progress)
    counts = {o: sum(r.outcome == o for r in results) for o in OUTCOMES}
    print(f"\n{len(results)} cases: " + ", ".join(f"{o} {n}" for o, n in counts.items()))
    report(results, lambda name: name.split("/", 1)[0] + "/" + name.rsplit("/", 1)[-1], a.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
