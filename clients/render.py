"""Human-readable text for the service's JSON: numbers with sensible digits, units where known.

Why here and not on the server: the JSON stays exact for programs; people at a terminal get
tables.  Units come from the model spec: each element kind's coefficient has an SI unit (a
spring's ``k`` is N/m), and a parameter shared by several elements keeps its unit only when
they agree.
"""
from __future__ import annotations

import math
from datetime import datetime
from typing import Any, Mapping, Sequence

# SI unit of each element coefficient (CONTRACT.md's kinds); power_spring's alpha depends on beta.
COEFFICIENT_UNITS: dict[tuple[str, str], str] = {
    ("spring", "k"): "N/m", ("damper", "c"): "N·s/m", ("cubic_spring", "k3"): "N/m³",
    ("quadratic_spring", "k2"): "N/m²", ("power_spring", "alpha"): "N/m^(1+β)",
    ("power_spring", "beta"): "–", ("cubic_damper", "c3"): "N·s/m³",
    ("quadratic_damper", "c2"): "N·s²/m²", ("coulomb", "fc"): "N", ("clearance", "k"): "N/m",
    ("clearance", "gap"): "m",
}


def parameter_units(spec: Mapping[str, Any] | None) -> dict[str, str]:
    """Parameter name -> unit from a model spec (JSON form); parameters of unknown unit omitted."""
    if not isinstance(spec, Mapping):
        return {}
    seen: dict[str, set[str]] = {}
    for el in spec.get("elements") or []:
        if not isinstance(el, Mapping):
            continue
        for coef, pname in (el.get("params") or {}).items():
            if isinstance(pname, str):
                unit = COEFFICIENT_UNITS.get((str(el.get("kind")), str(coef)), "?")
                seen.setdefault(pname, set()).add(unit)
    for force in (spec.get("forces") or {}).values():
        if isinstance(force, Mapping) and isinstance(force.get("gain"), str):
            seen.setdefault(force["gain"], set()).add("?")
    return {p: next(iter(u)) for p, u in seen.items() if len(u) == 1 and "?" not in u}


def num(x: Any, digits: int = 4) -> str:
    """``3.142e+08`` style only when needed: 4 significant digits, ``–`` for missing."""
    if x is None or isinstance(x, bool):
        return "–"
    try:
        v = float(x)
    except (TypeError, ValueError):
        return str(x)
    if not math.isfinite(v):
        return str(v)
    if v == 0:
        return "0"
    if 1e-3 <= abs(v) < 1e6:
        return f"{v:.{digits}g}"
    return f"{v:.{digits - 1}e}"


def row(cells: Sequence[str], widths: Sequence[int]) -> str:
    """One table line: cells padded to ``widths``, numbers right-aligned."""
    out = []
    for i, c in enumerate(cells):
        c = str(c)
        numeric = bool(c) and (c[0].isdigit() or c[0] in "-+–[")
        out.append(c.rjust(widths[i]) if numeric else c.ljust(widths[i]))
    return "  ".join(out).rstrip()


def table(header: Sequence[str], rows: Sequence[Sequence[str]],
          widths: Sequence[int] | None = None) -> str:
    """Columns padded to their widest cell (or to ``widths``), with a rule under the header."""
    if widths is None:
        widths = [max(len(str(c)) for c in col) for col in zip(header, *rows)] if rows else \
            [len(h) for h in header]
    return "\n".join([row(header, widths), row(["-" * w for w in widths], widths),
                      *(row(r, widths) for r in rows)])


def stream_widths(header: Sequence[str]) -> list[int]:
    """Fixed widths for a table printed row by row (``drift --watch`` to a file or pipe)."""
    return [max(len(h), 19 if h.startswith("time") else 9) for h in header]  # a local date-time


def _interval(ci: Any) -> str:
    if isinstance(ci, (list, tuple)) and len(ci) == 2:
        return f"[{num(ci[0])}, {num(ci[1])}]"
    return "–"


def validation_verdict(est: Mapping[str, Any]) -> Mapping[str, Any] | None:
    """The validation test's verdict in an estimate, when the service publishes one
    (``validation`` or ``best.validation`` with a boolean ``accepted``); else None."""
    for v in (est.get("validation"), (est.get("best") or {}).get("validation"),
              est.get("verdict")):
        if isinstance(v, Mapping) and isinstance(v.get("accepted"), bool):
            return v
    return None


def verdict_banner(est: Mapping[str, Any]) -> str | None:
    """One line for the top of a summary: MODEL REJECTED (with what to try next) or accepted."""
    v = validation_verdict(est)
    if v is None:
        return None
    stats = ", ".join(x for x in (
        f"T = {num(v.get('statistic'), 3)}" if v.get("statistic") is not None else "",
        f"p = {num(v.get('p_value'), 2)}" if v.get("p_value") is not None else "") if x)
    stats = f" ({stats})" if stats else ""
    if v["accepted"]:
        return f"validation: model accepted{stats}"
    hint = v.get("next") or v.get("hint") or ("the model does not explain the validation "
                                             "records; try `siva diagnose` to find what is "
                                             "missing before using these parameters")
    return f"MODEL REJECTED by the validation test{stats}: {hint}"


def render_estimate(name: str, est: Mapping[str, Any], units: Mapping[str, str]) -> str:
    """The estimate as a short report: state line, parameter table, modes, alarms."""
    n = est.get("n_recordings") or {}
    state = est.get("state") or ("converged" if est.get("converged") else "training")
    lines = []
    banner = verdict_banner(est)
    if banner:
        lines.append(banner)
    when = est.get("time")
    lines.append(f"{name}: {state}, epoch {est.get('epoch', 0)}, "
                 f"{n.get('train', 0)} train + {n.get('validation', 0)} validation recording(s)"
                 + (f", as of {local_time(when)} {local_zone()}" if when else ""))
    best = ((est.get("best") or {}).get("parameters")) or {}
    rows = []
    for p, s in (est.get("parameters") or {}).items():
        s = s or {}
        b = best.get(p) or {}
        rows.append([p, num(s.get("mean")), num(s.get("std")), _interval(s.get("ci95")),
                     num(b.get("value")), units.get(p, "")])
    if rows:
        lines.append(table(["parameter", "mean", "std", "95 % interval", "best", "unit"], rows))
    else:
        lines.append("no estimate yet")
    modal = est.get("modal") or {}
    freqs = modal.get("frequency_hz") or []
    if freqs:
        zetas = list(modal.get("damping_ratio") or []) + [None] * len(freqs)
        lines.append("modes (linearised about rest): " + ", ".join(
            f"{num(f)} Hz (ζ {num(100 * z, 3) + ' %' if z is not None else '–'})"
            for f, z in zip(freqs, zetas)))
    active = est.get("active_alarms") or []
    if active:
        lines.append(f"ACTIVE DRIFT ALARMS: {', '.join(map(str, active))}")
    return "\n".join(lines)


def local_zone() -> str:
    """The local time zone's name as the tables' headers show it (e.g. ``CET``, ``UTC``)."""
    return datetime.now().astimezone().tzname() or "local"


def local_time(t: Any, *, date: bool = True) -> str:
    """A UNIX time [s] as local wall-clock time, ``2026-11-25 09:41:07`` (``–`` if missing)."""
    try:
        return datetime.fromtimestamp(float(t)).strftime("%Y-%m-%d %H:%M:%S" if date
                                                          else "%H:%M:%S")
    except (TypeError, ValueError, OverflowError, OSError):
        return "–"


def _when(t: Any) -> str:
    return local_time(t)


def drift_rows(history: Sequence[Mapping[str, Any]], params: Sequence[str]
               ) -> list[list[str]]:
    """One row per history entry: epoch, time, converged, each parameter's mean."""
    rows = []
    for h in history:
        ps = h.get("parameters") or {}
        rows.append([str(h.get("epoch", "")), _when(h.get("time")),
                     "yes" if h.get("converged") else "no",
                     *[num((ps.get(p) or {}).get("mean") if isinstance(ps.get(p), Mapping)
                           else ps.get(p)) for p in params]])
    return rows


def drift_params(report: Mapping[str, Any]) -> list[str]:
    for h in report.get("history") or []:
        if h.get("parameters"):
            return list(h["parameters"])
    return []


def drift_header(params: Sequence[str], units: Mapping[str, str]) -> list[str]:
    return ["epoch", f"time ({local_zone()})", "converged",
            *[f"{p} [{units[p]}]" if units.get(p) else p for p in params]]


def render_alarms(report: Mapping[str, Any]) -> str:
    """Alarms as a table (newest last): state, change, the records where it was raised,
    confirmed or cleared, and the detector's one-sentence message."""
    alarms = report.get("alarms") or []
    if not alarms:
        return "no drift alarms"
    rows = []
    for a in alarms:
        state = str(a.get("state") or ("active" if a.get("active") else "cleared"))
        rel = a.get("change_rel")
        rows.append([str(a.get("id", "")), str(a.get("parameter", "")),
                     state.upper() if a.get("active") else state,
                     f"{100 * rel:+.1f} %" if isinstance(rel, (int, float)) else "–",
                     str(a.get("raised_index", a.get("epoch", "")) or "–"),
                     local_time(a.get("raised_time")), str(a.get("message", ""))])
    return table(["alarm", "quantity", "state", "change", "record", f"raised ({local_zone()})",
                  "message"], rows)


def render_drift(name: str, report: Mapping[str, Any], units: Mapping[str, str],
                 last: int = 15) -> str:
    """The last ``last`` history entries as a table, then the alarms."""
    params = drift_params(report)
    hist = list(report.get("history") or [])
    out = [f"{name}: {len(hist)} estimate(s) in the history"
           + (f", showing the last {last}" if len(hist) > last else "")]
    if hist:
        out.append(table(drift_header(params, units), drift_rows(hist[-last:], params)))
    out.append(render_alarms(report))
    return "\n".join(out)


# --------------------------------------------------------------------------- other commands
def _size(n: Any) -> str:
    try:
        v = float(n)
    except (TypeError, ValueError):
        return "–"
    for unit in ("B", "kB", "MB", "GB"):
        if v < 1000 or unit == "GB":
            return f"{v:.0f} {unit}" if unit == "B" else f"{v:.1f} {unit}"
        v /= 1000
    return "–"


def recordings_table(recs: Sequence[Mapping[str, Any]], *, with_memory: bool = True) -> str:
    """Recordings (or upload acknowledgements) as a table with units and local times."""
    header = ["#", "id", "file", "role", "samples", "fs [Hz]", "duration [s]", "size",
              f"received ({local_zone()})"]
    if with_memory:
        header.append("in training")
    rows = []
    for r in recs:
        role = str(r.get("role", "–")) + (" (auto)" if r.get("role_source") == "auto" else "")
        row_ = [str(r.get("index", "–")), str(r.get("id", "–")),
                str(r.get("filename") or r.get("path") or "–"), role,
                str(r.get("n_samples", "–")), num(r.get("fs")), num(r.get("duration_s")),
                _size(r.get("bytes")), local_time(r.get("received_at"))]
        if with_memory:
            row_.append("yes" if r.get("in_memory") else "no")
        rows.append(row_)
    return table(header, rows)


def render_recordings(name: str, body: Mapping[str, Any]) -> str:
    recs = list(body.get("recordings") or [])
    n = body.get("n_recordings") or {}
    head = (f"{name}: {len(recs)} recording(s), {n.get('train', 0)} train + "
            f"{n.get('validation', 0)} validation")
    return head + ("\n" + recordings_table(recs) if recs else "")


def render_uploads(acks: Sequence[Mapping[str, Any]]) -> str:
    """What ``upload`` / ``upload-folder`` stored: one row per file, then duplicates and
    the server's warnings (if any) one per line."""
    lines = [recordings_table(acks, with_memory=False)]
    for a in acks:
        what = a.get("filename") or a.get("path")
        if a.get("duplicate"):
            lines.append(f"note: {what}: already stored (same bytes), not added again")
        for w in a.get("warnings") or []:
            lines.append(f"warning: {what}: {w}")
    return "\n".join(lines)


def render_registered(name: str, ack: Mapping[str, Any]) -> str:
    spec = ack.get("spec") if isinstance(ack.get("spec"), Mapping) else {}
    dofs = ack.get("dofs") or (spec or {}).get("dofs") or []
    free = ack.get("free_parameters") or []
    units = parameter_units(spec)
    state = ("registered" if ack.get("created", True)
             else "already registered with this spec (unchanged)")
    return (f"{name}: {state}; {len(dofs)} DOF(s) ({', '.join(map(str, dofs))}), "
            f"{len(free)} free parameter(s): "
            + ", ".join(f"{p} [{units[p]}]" if units.get(p) else p for p in free))


def render_reset(name: str, before: Mapping[str, Any] | None, after: Mapping[str, Any]) -> str:
    """A short summary of ``drift reset`` (the server answers with the whole report)."""
    alarms = len((before or {}).get("alarms") or [])
    active = (before or {}).get("active_alarms") or []
    hist = len(after.get("history") or [])
    rule = after.get("rule") or {}
    base = rule.get("baseline_records")
    out = [f"{name}: drift reference and alarms forgotten"
           + (f" ({alarms} alarm(s), active: {', '.join(map(str, active)) or 'none'})"
              if before is not None else ""),
           "the next " + (f"{base} " if base else "") + "record(s) form a new baseline; "
           f"the estimate history ({hist} entries) is kept"]
    return "\n".join(out)


def render_deleted(name: str, body: Mapping[str, Any]) -> str:
    logs = body.get("logs") or {}
    n = body.get("recordings")
    out = f"{name}: deleted" + (f" with its {n} recording(s)" if n is not None else "")
    action = logs.get("action")
    if action == "deleted":
        out += f"; its MCAP event logs were deleted ({logs.get('files', 0)} file(s))"
    elif action == "archived":
        out += (f"; its MCAP event logs ({logs.get('files', 0)} file(s)) were archived to "
                f"{logs.get('archive')} on the server")
    elif action == "none":
        out += "; it had no MCAP event logs"
    return out
