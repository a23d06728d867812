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
    return [max(len(h), 9) for h in header]


def _interval(ci: Any) -> str:
    if isinstance(ci, (list, tuple)) and len(ci) == 2:
        return f"[{num(ci[0])}, {num(ci[1])}]"
    return "–"


def render_estimate(name: str, est: Mapping[str, Any], units: Mapping[str, str]) -> str:
    """The estimate as a short report: state line, parameter table, modes, alarms."""
    n = est.get("n_recordings") or {}
    state = est.get("state") or ("converged" if est.get("converged") else "training")
    lines = [f"{name}: {state}, epoch {est.get('epoch', 0)}, "
             f"{n.get('train', 0)} train + {n.get('validation', 0)} validation recording(s)"]
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


def _when(t: Any) -> str:
    try:
        return datetime.fromtimestamp(float(t)).strftime("%H:%M:%S")
    except (TypeError, ValueError, OverflowError, OSError):
        return "–"


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
    return ["epoch", "time", "converged",
            *[f"{p} [{units[p]}]" if units.get(p) else p for p in params]]


def render_alarms(report: Mapping[str, Any]) -> str:
    alarms = report.get("alarms") or []
    if not alarms:
        return "no drift alarms"
    rows = [[str(a.get("id", "")), str(a.get("parameter", "")),
             "ACTIVE" if a.get("active") else "cleared", str(a.get("direction", "")),
             (f"{100 * a['change_rel']:+.1f} %" if a.get("change_rel") is not None else "–"),
             str(a.get("epoch", ""))] for a in alarms]
    return table(["alarm", "parameter", "state", "direction", "change", "epoch"], rows)


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
