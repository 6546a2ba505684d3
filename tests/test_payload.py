"""The payload parser is total (a Message or a PayloadError, for any bytes), and the source guard's rules."""
from __future__ import annotations

import json
import math

from hypothesis import given, settings, strategies as st

from controller.transport.guard import SourceGuard
from controller.transport.payload import (INT_DIGITS, MAX_DEPTH, MAX_PAYLOAD_BYTES, Message, PayloadError, _number,
                                          decode, encode, nesting_too_deep, parse_number, parse_word)

# JSON documents of any shape: strings with brackets, quotes and escapes; numbers of any size.
scalars = (st.none() | st.booleans() | st.integers(-(10 ** 30), 10 ** 30)
           | st.floats(allow_nan=False, allow_infinity=False) | st.text(alphabet=st.sampled_from('ab[]{}"\\\u00e9 ,:'), max_size=12))
documents = st.recursive(scalars, lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=4), c, max_size=4),
                         max_leaves=30)


def depth(x) -> int:
    """Nesting depth of a decoded document (a reference for the iterative scan; hypothesis keeps it shallow)."""
    if isinstance(x, list):
        return 1 + max((depth(v) for v in x), default=0)
    if isinstance(x, dict):
        return 1 + max((depth(v) for v in x.values()), default=0)
    return 0


def longest_int(x) -> int:
    """Digits of the longest integer in a decoded document."""
    if isinstance(x, list):
        return max((longest_int(v) for v in x), default=0)
    if isinstance(x, dict):
        return max((longest_int(v) for v in x.values()), default=0)
    return len(str(abs(x))) if type(x) is int else 0


def total(parse, data):
    """``parse(data)``: a Message, or a PayloadError; anything else escapes and fails the test."""
    try:
        return parse(data)
    except PayloadError:
        return None


hostile = st.one_of(
    st.binary(max_size=200),
    documents.map(lambda d: json.dumps(d).encode()),
    st.builds(lambda v, n: (b'{"value": ' + b"[" * n + v + b"]" * n + b"}"), st.sampled_from([b"1", b"NaN", b'"x"']),
              st.integers(0, 3000)),
    st.integers(1, 5000).map(lambda n: b'{"value": ' + b"9" * n + b"}"),
    st.sampled_from([b"NaN", b"Infinity", b"-Infinity", b"1e999", b"-1e400", b"true", b"null", b'"60"', b"[60]",
                     b"{}"]).map(lambda v: b'{"t": 0, "seq": 1, "value": ' + v + b"}"),
    st.integers(0, 3).map(lambda k: [b"[" * 100_000, b"{" * 50_000, b" " * (MAX_PAYLOAD_BYTES + 1),
                                     b'{"value": 1, "pad": "' + b"x" * 10 ** 6 + b'"}'][k]),
    documents.map(lambda d: json.dumps({"value": 1.0, "seq": 3, "extra": d}).encode()),
    # DESIGN.md's fields alone, of any scalar (parse_number's fast path), duplicated keys included
    st.fixed_dictionaries({}, optional={k: scalars | st.integers(-(10 ** 20), 10 ** 20) | st.text(max_size=70)
                                        for k in ("t", "seq", "value", "src")}).map(
        lambda d: json.dumps(d).encode() if d else b'{"value": 1, "value": true}'),
)


@settings(max_examples=200, deadline=None)
@given(hostile, st.integers(0, 10))
def test_parser_is_total(data, cut):
    """Every payload, whole or truncated: a finite-valued Message or a PayloadError, nothing else; parse_number's
    fast path takes exactly what the full parser takes, to the same message."""
    for d in (data, data[: len(data) * cut // 10]):
        assert total(parse_number, d) == total(lambda x: _number(decode(x)), d)
        for parse in (parse_number, parse_word):
            m = total(parse, d)
            if m is not None:
                assert isinstance(m, Message)
                assert len(d) <= MAX_PAYLOAD_BYTES
                if parse is parse_number:
                    assert isinstance(m.value, float) and math.isfinite(m.value)
                assert m.seq is None or (type(m.seq) is int and len(str(abs(m.seq))) <= INT_DIGITS)
                assert m.t_s is None or math.isfinite(m.t_s)


@settings(max_examples=150, deadline=None)
@given(documents)
def test_nesting_scan_matches_the_decoded_depth(doc):
    data = json.dumps(doc).encode()
    assert nesting_too_deep(data) == (depth(doc) > MAX_DEPTH)


@given(st.integers(0, 3 * MAX_DEPTH))
def test_nesting_limit_is_exact(n):
    data = b'{"value": 1, "x": ' + b"[" * n + b"]" * n + b"}"
    assert nesting_too_deep(data) == (n + 1 > MAX_DEPTH)


@settings(max_examples=150, deadline=None)
@given(st.floats(allow_nan=False, allow_infinity=False) | st.integers(-(10 ** 15), 10 ** 15),
       st.integers(0, 2 ** 53), st.floats(0, 1e9),
       st.dictionaries(st.text(max_size=6).filter(lambda k: k not in ("t", "seq", "value", "src")), documents,
                       max_size=3))
def test_a_valid_message_round_trips(value, seq, t_s, extra):
    """DESIGN.md payloads with extra fields of any shape parse to their fields, within the limits."""
    data = encode(t_s, seq, value, **extra)
    doc = json.loads(data)
    if len(data) > MAX_PAYLOAD_BYTES or depth(doc) > MAX_DEPTH or longest_int(doc) > INT_DIGITS:
        assert total(parse_number, data) is None
        return
    m = parse_number(data)
    assert m == Message(float(value), seq, float(t_s), None)


@given(st.sampled_from([float("nan"), float("inf"), -float("inf")]))
def test_non_finite_values_are_refused(v):
    assert total(parse_number, encode(0.0, 1, v)) is None


def test_faults_name_the_problem():
    cases = {
        b'{"value": ' + b"1" * 400 + b"}": "digits",
        b'{"value": NaN}': "finite",
        b"[" * 100_000: "bytes",
        b"[" * 4000: "nested",
        b'{"t": 1}': "no value",
        b"\xff": "not JSON",
        b'{"value": 1, "seq": "7"}': "seq",
    }
    for data, word in cases.items():
        try:
            parse_number(data)
        except PayloadError as exc:
            assert word in str(exc), (data[:40], str(exc))
        else:
            raise AssertionError(data[:40])


def test_words_for_ctrl_mode():
    assert parse_word(encode(1.0, 2, "ff+kf")).value == "ff+kf"
    for bad in (encode(1.0, 2, 3.0), encode(1.0, 2, ""), encode(1.0, 2, "x" * 1000), b'{"value": ["pid"]}'):
        assert total(parse_word, bad) is None


def test_decode_refuses_a_size_before_reading_it():
    assert total(decode, b"{}" + b" " * MAX_PAYLOAD_BYTES) is None
    assert decode(b'{"a": 1}', max_bytes=8) == {"a": 1}


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


@given(st.lists(st.integers(0, 10 ** 6), min_size=1, max_size=50, unique=True))
def test_guard_believes_one_source_with_increasing_seq(seqs):
    seqs.sort()
    g = SourceGuard(0.05, Clock())
    assert all(g.believe("valve", s) for s in seqs)
    assert not g.contested


@given(st.lists(st.tuples(st.booleans(), st.integers(0, 1000)), min_size=1, max_size=80))
def test_guard_never_believes_a_second_source_while_the_first_lives(events):
    """Interleaved samples from the valve and a forger within release_s: the forger is never believed."""
    clock = Clock()
    g = SourceGuard(0.05, clock)
    assert g.believe("valve", 0)
    seq = 0
    for forger, fseq in events:
        clock.t += 0.001
        if forger:
            assert not g.believe(None if fseq % 2 else "forger", fseq)
        else:
            seq += 1
            assert g.believe("valve", seq)
    assert g.contested == any(f for f, _ in events)


def test_guard_flags_seq_running_backwards_and_replays():
    g = SourceGuard(0.05, Clock())
    assert g.believe(None, 10)
    assert not g.believe(None, 10)
    assert not g.believe(None, 3)
    assert not g.believe(None, None)
    assert g.believe(None, 11)
    assert g.contested


def test_guard_accepts_a_restart_after_silence_unless_contested():
    clock = Clock()
    g = SourceGuard(0.05, clock)
    assert g.believe("valve-1", 500)
    clock.t = 0.2  # the node died; the loop went safe; a new node (new session id) starts
    assert g.believe("valve-2", 0)
    assert g.believe("valve-2", 1)
    assert not g.believe("forger", 1000)  # contested from here on
    clock.t = 1.0  # the node dies again: nobody else is believed, whatever its seq
    assert not g.believe("forger", 1001)
    assert not g.believe("valve-3", 0)
