"""Input limits of the service: spec size, nesting, number size, plausible physical ranges.

Why a module of its own: ``Structure.from_dict`` checks that a spec *means* something; this
checks that it is small and sane enough to be worth training, before any work is spent on it.
Without these limits a 5000-digit integer, 10 000 nested brackets or a 900-deep field reached
the code that stores, serialises or trains and ended as a 500, and 1000 parameters or a mass
of 1e-320 kg were accepted and then trained for minutes into empty estimates.

Every refusal is a domain error (``service/errors.py``: :class:`TooLarge`, :class:`Invalid`,
:class:`Unreadable`) with a message naming the offending field and the setting that
changes the limit; the API maps them to 413 / 422 / 400.
"""
from __future__ import annotations

import json
import math
import tomllib
from typing import Any

from .errors import Invalid, ServiceError, TooLarge, Unreadable
from .settings import Settings

#: integers with more digits than this are refused while parsing (before any conversion)
MAX_INT_DIGITS = 20
#: every number in a spec must lie in [-MAX_MAGNITUDE, MAX_MAGNITUDE]
MAX_MAGNITUDE = 1e12
#: positive physical values (masses, scales) must be at least this
MIN_POSITIVE = 1e-12
#: strings in a spec (names, kinds) are at most this long
MAX_STRING = 256


# --------------------------------------------------------------------------- parsing
def _parse_int(text: str) -> int:
    digits = len(text.lstrip("+-"))
    if digits > MAX_INT_DIGITS:
        raise Invalid(f"integer with {digits} digits (at most {MAX_INT_DIGITS})")
    return int(text)


def _parse_float(text: str) -> float:
    if len(text) > 64:
        raise Invalid(f"number literal of {len(text)} characters (at most 64)")
    x = float(text)
    if not math.isfinite(x):
        raise Invalid(f"number {text[:40]} is out of range (not finite)")
    return x


def _no_constant(name: str) -> Any:
    raise Invalid(f"{name} is not a number JSON allows")


def parse_spec_body(raw: bytes, media: str, settings: Settings) -> Any:
    """The body of PUT /v1/systems/{name} as a Python value, or an Unreadable / TooLarge / Invalid error.

    Bounded: the size first, then the parser's own recursion guard (its RecursionError
    is a refusal, not a crash), then integers limited to ``MAX_INT_DIGITS`` digits while
    parsing (Python refuses > 4300 digits with a ValueError, and > 308 digits overflow a
    float later), then the nesting depth of the result.
    """
    if len(raw) > settings.max_spec_bytes:
        raise TooLarge(f"model spec of {len(raw)} bytes: the limit is "
                       f"{settings.max_spec_bytes} bytes (SIVA_MAX_SPEC_BYTES)")
    if not raw.strip():
        raise Unreadable("request body is empty: expected the model spec as JSON")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise Unreadable(f"request body: not UTF-8 (byte {exc.start})") from None
    try:
        if media == "toml":
            value: Any = tomllib.loads(text, parse_float=_parse_float)
        else:
            value = json.loads(text, parse_int=_parse_int, parse_float=_parse_float,
                               parse_constant=_no_constant)
    except ServiceError as exc:
        raise type(exc)(f"request body: {exc.detail}") from None
    except json.JSONDecodeError as exc:
        raise Unreadable(f"request body: invalid JSON at line {exc.lineno}, column "
                         f"{exc.colno}: {exc.msg}") from None
    except tomllib.TOMLDecodeError as exc:
        raise Unreadable(f"request body: invalid TOML ({exc})") from None
    except RecursionError:
        raise Invalid("request body: nested too deeply (at most "
                      f"{settings.max_spec_depth} levels, SIVA_MAX_SPEC_DEPTH)") from None
    except (ValueError, OverflowError) as exc:  # e.g. a TOML integer of 5000 digits
        raise Invalid(f"request body: a value is out of range ({str(exc)[:120]})") from None
    check_value(value, settings)
    return value


def check_value(value: Any, settings: Settings) -> None:
    """Depth, string length and number range of a parsed spec (iterative: no recursion)."""
    stack: list[tuple[Any, str, int]] = [(value, "spec", 1)]
    while stack:
        v, where, depth = stack.pop()
        if isinstance(v, dict):
            if depth > settings.max_spec_depth:
                raise Invalid(f"{where}: nested deeper than {settings.max_spec_depth} "
                              "levels (SIVA_MAX_SPEC_DEPTH)")
            for k, x in v.items():
                key = str(k)
                if len(key) > MAX_STRING:
                    raise Invalid(f"{where}: a key of {len(key)} characters "
                                  f"(at most {MAX_STRING})")
                stack.append((x, f"{where}.{key}" if where != "spec" else key, depth + 1))
        elif isinstance(v, list):
            if depth > settings.max_spec_depth:
                raise Invalid(f"{where}: nested deeper than {settings.max_spec_depth} "
                              "levels (SIVA_MAX_SPEC_DEPTH)")
            for i, x in enumerate(v):
                stack.append((x, f"{where}[{i}]", depth + 1))
        elif isinstance(v, str):
            if len(v) > MAX_STRING:
                raise Invalid(f"{where}: string of {len(v)} characters "
                              f"(at most {MAX_STRING})")
        elif isinstance(v, bool) or v is None:
            continue
        elif isinstance(v, int):
            if abs(v) > 10 ** MAX_INT_DIGITS:
                raise Invalid(f"{where}: integer too large")
            _check_magnitude(float(v), where)
        elif isinstance(v, float):
            if not math.isfinite(v):
                raise Invalid(f"{where}: {v} is not a finite number")
            _check_magnitude(v, where)


def _check_magnitude(x: float, where: str) -> None:
    if abs(x) > MAX_MAGNITUDE:
        raise Invalid(f"{where}: {x:g} is outside the plausible range "
                      f"[-{MAX_MAGNITUDE:g}, {MAX_MAGNITUDE:g}] (use SI units)")


# --------------------------------------------------------------------------- structure
def check_structure(structure: Any, settings: Settings) -> None:
    """Size and physical plausibility of a validated Structure (422 otherwise)."""
    if len(structure.dofs) > settings.max_dofs:
        raise Invalid(f"model spec: {len(structure.dofs)} DOFs, at most "
                      f"{settings.max_dofs} (SIVA_MAX_DOFS)")
    if len(structure.elements) > settings.max_elements:
        raise Invalid(f"model spec: {len(structure.elements)} elements, at most "
                      f"{settings.max_elements} (SIVA_MAX_ELEMENTS)")
    if len(structure.free) > settings.max_parameters:
        raise Invalid(f"model spec: {len(structure.free)} free parameters, at most "
                      f"{settings.max_parameters} (SIVA_MAX_PARAMETERS)")
    for dof, m in structure.mass.items():
        if not MIN_POSITIVE <= m <= MAX_MAGNITUDE:
            raise Invalid(f"model spec: mass.{dof} = {m:g} kg is outside the plausible "
                          f"range [{MIN_POSITIVE:g}, {MAX_MAGNITUDE:g}] kg")
    for p, info in structure.parameters.items():
        scale = getattr(info, "scale", None)
        if scale is not None and not MIN_POSITIVE <= scale <= MAX_MAGNITUDE:
            raise Invalid(f"model spec: parameters.{p}.scale = {scale:g} is outside the "
                          f"plausible range [{MIN_POSITIVE:g}, {MAX_MAGNITUDE:g}]")


def check_sampling_rate(fs: float, filename: str, settings: Settings) -> None:
    """A recording's sampling rate must be physically plausible (422 otherwise)."""
    lo, hi = settings.min_sampling_rate_hz, settings.max_sampling_rate_hz
    if not (math.isfinite(fs) and lo <= fs <= hi):
        raise Invalid(f"{filename}: sampling rate {fs:g} Hz is outside the accepted "
                      f"range [{lo:g}, {hi:g}] Hz (SIVA_MIN_SAMPLING_RATE_HZ, "
                      "SIVA_MAX_SAMPLING_RATE_HZ); is the time column in seconds?")
