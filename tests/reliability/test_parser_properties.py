"""Property-based tests (hypothesis) of the parsers a request reaches: the spec body, the
recording readers behind an upload, and the event-log reader after torn writes.  The
property is always the same: any input gives a value or the parser's documented refusal,
never another exception (which the service would turn into a 500)."""
from __future__ import annotations

import json
import random
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from service.api.http_errors import status_of
from service.errors import ServiceError
from service.limits import check_structure, parse_spec_body
from service.settings import Settings
from siva_core import RecordingError, SpecError, Structure

SETTINGS = Settings()
FAST = settings(max_examples=150, deadline=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

# JSON-ish values, including the shapes that once broke the service: huge integers, deep
# nesting, floats at the edges of the range
leaves = (st.none() | st.booleans() | st.integers(min_value=-10 ** 400, max_value=10 ** 400)
          | st.floats(allow_nan=False) | st.text(max_size=20))
json_values = st.recursive(leaves, lambda inner: st.lists(inner, max_size=4)
                           | st.dictionaries(st.text(max_size=8), inner, max_size=4),
                           max_leaves=30)

#: the exceptions SivaService.put_system maps to a 4xx
SPEC_REFUSALS = (ServiceError, SpecError, TypeError, ValueError, KeyError, AttributeError,
                 OverflowError, RecursionError)


def _spec_pipeline(raw: bytes, kind: str = "json") -> None:
    """What PUT /v1/systems/{name} does with a body, up to storing it."""
    value = parse_spec_body(raw, kind, SETTINGS)
    structure = Structure.from_dict(value)
    check_structure(structure, SETTINGS)
    json.dumps(structure.spec)  # stored and served: must serialise


@FAST
@given(st.binary(max_size=300))
def test_spec_body_bytes(raw):
    try:
        _spec_pipeline(raw)
    except SPEC_REFUSALS:
        pass


@FAST
@given(json_values)
def test_spec_body_json_values(value):
    raw = json.dumps(value).encode()
    try:
        _spec_pipeline(raw)
    except SPEC_REFUSALS:
        pass


@FAST
@given(st.text(max_size=300))
def test_spec_body_toml_text(text):
    try:
        _spec_pipeline(text.encode(), "toml")
    except SPEC_REFUSALS:
        pass


@FAST
@given(depth=st.integers(1, 20000), kind=st.sampled_from(["json", "toml"]))
def test_spec_nesting_is_refused_with_4xx(depth, kind):
    raw = (b"[" * depth + b"]" * depth) if kind == "json" else (b"x = " + b"[" * depth)
    try:
        parse_spec_body(raw, kind, SETTINGS)
    except ServiceError as exc:
        assert status_of(exc) in (400, 413, 422)


@FAST
@given(digits=st.integers(1, 6000))
def test_spec_integer_sizes(digits):
    raw = b'{"mass": {"x": ' + b"7" * digits + b"}}"
    try:
        v = parse_spec_body(raw, "json", SETTINGS)
    except ServiceError as exc:
        assert status_of(exc) == 422 and digits > 12
    else:
        assert v["mass"]["x"] == int("7" * digits)


# --------------------------------------------------------------------------- recordings
@pytest.fixture(scope="module")
def linear_structure():
    return Structure.from_dict({"name": "p", "dofs": ["x"], "mass": {"x": 0.05}, "elements": [
        {"kind": "spring", "between": ["x", "ground"], "params": {"k": "k"}}]})


GOOD_CSV = b"time,disp_x\n" + b"".join(f"{i / 1000},{(i % 7) / 1000}\n".encode()
                                       for i in range(300))


def _mutate(data: bytes, rnd: random.Random, n: int) -> bytes:
    b = bytearray(data)
    for _ in range(n):
        op = rnd.randrange(3)
        pos = rnd.randrange(len(b) + 1)
        if op == 0 and b:
            b[min(pos, len(b) - 1)] = rnd.randrange(256)
        elif op == 1:
            b[pos:pos] = bytes([rnd.randrange(256)])
        elif b:
            del b[min(pos, len(b) - 1)]
    return bytes(b)


@FAST
@given(fmt=st.sampled_from(["csv", "json", "npz", "mcap"]), data=st.binary(max_size=400))
def test_upload_parser_arbitrary_bytes(linear_structure, fmt, data):
    from service.storage.uploads import parse_upload

    try:
        parse_upload(linear_structure, data, fmt, "u")
    except RecordingError:
        pass


@FAST
@given(seed=st.integers(0, 2 ** 32 - 1), n=st.integers(1, 20))
def test_upload_parser_mutated_csv(linear_structure, seed, n):
    from service.storage.uploads import parse_upload

    try:
        parse_upload(linear_structure, _mutate(GOOD_CSV, random.Random(seed), n), "csv", "u")
    except RecordingError:
        pass


# --------------------------------------------------------------------------- event log
@pytest.fixture(scope="module")
def event_log(tmp_path_factory) -> tuple[bytes, list[str]]:
    """A finished log of 12 recording events; returns its bytes and the event ids."""
    from service.storage.eventlog import EventLog

    d = tmp_path_factory.mktemp("log")
    log = EventLog(d)
    log.log_spec("s", {"name": "s"})
    ids = [f"r{i:06d}" for i in range(12)]
    for i, rid in enumerate(ids):
        log.log_recording("s", rid, "train", GOOD_CSV + str(i).encode(), "csv", i)
    log.close()
    (p,) = (d / "logs" / "s").glob("*.mcap")
    return p.read_bytes(), ids


def _read(tmp: Path, raw: bytes) -> list:
    from service.storage.eventlog import read_events

    p = tmp / "x.mcap"
    p.write_bytes(raw)
    return read_events(p)


@FAST
@given(cut=st.integers(0, 10 ** 6))
def test_log_cut_anywhere_keeps_a_prefix(tmp_path_factory, event_log, cut):
    from mcap.exceptions import McapError

    raw, ids = event_log
    cut = cut % (len(raw) + 1)
    try:
        events = _read(tmp_path_factory.mktemp("c"), raw[:cut])
    except McapError:
        assert cut < 8 and raw[:cut] != raw[:8][:cut]  # only a broken magic is refused
        return
    got = [e.event.id for e in events if e.topic == "/siva/recording"]
    assert got == ids[:len(got)]


@FAST
@given(seed=st.integers(0, 2 ** 32 - 1))
def test_log_torn_chunk_keeps_later_events(tmp_path_factory, event_log, seed):
    """Garbage over the middle of the file (a torn write, a bad sector): the events before
    and after it are still read, in order."""
    raw, ids = event_log
    rnd = random.Random(seed)
    a = rnd.randrange(len(raw) // 3, len(raw) // 2)
    n = rnd.randrange(1, 200)
    torn = raw[:a] + bytes(rnd.randrange(256) for _ in range(n)) + raw[a + n:]
    events = _read(tmp_path_factory.mktemp("t"), torn)
    got = [e.event.id for e in events if e.topic == "/siva/recording"]
    assert got == sorted(got) and set(got) <= set(ids)
    assert got[-1] == ids[-1], "the events after the torn chunk were lost"
    assert len(got) >= len(ids) - 3
