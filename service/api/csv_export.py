"""CSV exports of a system's results: what people paste into a spreadsheet or a report.

Why CSV (and not the JSON reshaped by each user): the estimate, the per-record fits and the
history are tables, and a spreadsheet needs a flat file whose column names carry the units
(``k1 [N/m]``) and whose times read as times (``time_utc``, ``2026-11-25 09:41:07.123``).
Headers are ASCII (``N*s/m^3``, not ``N·s/m³``) so that Excel opens the file without an
import dialog; numbers are written with ``repr`` precision (nothing is rounded away).

Four tables, built from the payloads the API already serves (nothing is recomputed):

- ``estimates``: the current estimate, one row per quantity (parameters, then the linear
  modes' frequencies and damping ratios): value, standard deviation, 95 % interval, source;
- ``records``: the per-record output-error fits (one row per record: its parameters, their
  standard errors, its modes), the series the drift detector tests;
- ``drift``: the published estimates over time (one row per snapshot), the drift history;
- ``alarms``: the drift alarms with their states, records, change and message.
"""
from __future__ import annotations

import csv
import io
import math
from datetime import datetime, timezone
from typing import Any, Mapping, Sequence

#: what can be exported (``GET /v1/systems/{name}/export/{what}.csv``)
EXPORTS = ("estimates", "records", "drift", "alarms")
#: units of the modal quantities the service derives (``f1_hz``, ``zeta1``, ...)
MODAL_UNITS = {"f": "Hz", "zeta": "-"}


def ascii_unit(unit: str | None) -> str:
    """A unit for a CSV header: ASCII only (``N·s/m³`` -> ``N*s/m^3``), ``-`` if unknown."""
    if not unit:
        return ""
    table = {"·": "*", "³": "^3", "²": "^2", "β": "beta", "–": "-", "α": "alpha"}
    return "".join(table.get(c, c) for c in unit)


def modal_unit(name: str) -> str:
    """``f1_hz`` -> Hz, ``zeta2`` -> - (damping ratio)."""
    if name.startswith("f") and name.endswith("_hz"):
        return "Hz"
    if name.startswith("zeta"):
        return "-"
    return ""


def column(name: str, unit: str | None) -> str:
    u = ascii_unit(unit)
    return f"{name} [{u}]" if u else name


def utc_text(t: Any) -> str:
    """UNIX seconds -> ``2026-11-25 09:41:07.123`` (UTC; a spreadsheet parses it as a date)."""
    try:
        return datetime.fromtimestamp(float(t), tz=timezone.utc).strftime(
            "%Y-%m-%d %H:%M:%S.%f")[:-3]
    except (TypeError, ValueError, OverflowError, OSError):
        return ""


def _cell(v: Any) -> Any:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else ""
    return v


def to_csv(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    for r in rows:
        w.writerow([_cell(v) for v in r])
    return buf.getvalue()


def _modal_names(entries: Sequence[Mapping[str, Any]], key: str = "modal") -> list[str]:
    names: list[str] = []
    for e in entries:
        m = e.get(key)
        if isinstance(m, Mapping):
            for n in m:
                if n not in names and isinstance(m.get(n), (int, float)):
                    names.append(n)
    return names


# --------------------------------------------------------------------------- tables
def estimates_table(est: Mapping[str, Any], units: Mapping[str, str]
                    ) -> tuple[list[str], list[list[Any]]]:
    """The current estimate: parameters (headline), then modal quantities."""
    header = ["quantity", "unit", "value", "std", "ci95_low", "ci95_high", "source",
              "n_records", "epoch", "time_utc"]
    when = utc_text(est.get("time"))
    source = est.get("estimate_source") or ""
    rows: list[list[Any]] = []
    for p, s in (est.get("parameters") or {}).items():
        s = s if isinstance(s, Mapping) else {"mean": s}
        ci = s.get("ci95") if isinstance(s.get("ci95"), (list, tuple)) else [None, None]
        rows.append([p, ascii_unit(units.get(p)), s.get("mean", s.get("value")), s.get("std"),
                     ci[0], ci[1], s.get("source") or source, s.get("n"), est.get("epoch"),
                     when])
    modal = est.get("modal") or {}
    freqs = modal.get("frequency_hz") or []
    zetas = modal.get("damping_ratio") or []
    for k, f in enumerate(freqs):
        rows.append([f"f{k + 1}_hz", "Hz", f, None, None, None, "linearised about rest",
                     None, est.get("epoch"), when])
        if k < len(zetas):
            rows.append([f"zeta{k + 1}", "-", zetas[k], None, None, None,
                         "linearised about rest", None, est.get("epoch"), when])
    return header, rows


def records_table(report: Mapping[str, Any], units: Mapping[str, str]
                  ) -> tuple[list[str], list[list[Any]]]:
    """The per-record fits of the drift report (``records``), oldest first."""
    recs = [r for r in report.get("records") or [] if isinstance(r, Mapping)]
    params: list[str] = []
    for r in recs:
        for p in (r.get("parameters") or {}):
            if p not in params:
                params.append(p)
    modal = _modal_names(recs)
    header = (["record_index", "record_id", "received_utc", "fit_ok"]
              + [column(p, units.get(p)) for p in params]
              + [column(f"{p}_se", units.get(p)) for p in params]
              + [column(m, modal_unit(m)) for m in modal]
              + [column(f"{m}_se", modal_unit(m)) for m in modal]
              + ["cost", "function_evaluations", "fit_seconds [s]"])
    rows = []
    for r in recs:
        ps, se = r.get("parameters") or {}, r.get("se") or {}
        md, mse = r.get("modal") or {}, r.get("modal_se") or {}
        rows.append([r.get("index"), r.get("id"), utc_text(r.get("time")), r.get("ok")]
                    + [ps.get(p) for p in params] + [se.get(p) for p in params]
                    + [md.get(m) for m in modal] + [mse.get(m) for m in modal]
                    + [r.get("cost"), r.get("nfev"), r.get("seconds")])
    return header, rows


def drift_table(report: Mapping[str, Any], units: Mapping[str, str]
                ) -> tuple[list[str], list[list[Any]]]:
    """The published estimates over time (``history``): mean and 95 % interval of each
    parameter per snapshot, the linear modes, the trainer epoch for reference."""
    hist = [h for h in report.get("history") or [] if isinstance(h, Mapping)]
    params: list[str] = []
    for h in hist:
        for p in (h.get("parameters") or {}):
            if p not in params:
                params.append(p)
    n_modes = max((len((h.get("modal") or {}).get("frequency_hz") or []) for h in hist),
                  default=0)
    header = (["time_utc", "epoch", "converged", "source"]
              + [c for p in params for c in (column(p, units.get(p)),
                                             column(f"{p}_ci95_low", units.get(p)),
                                             column(f"{p}_ci95_high", units.get(p)))]
              + [c for k in range(n_modes) for c in (f"f{k + 1} [Hz]", f"zeta{k + 1} [-]")])
    rows = []
    for h in hist:
        row: list[Any] = [utc_text(h.get("time")), h.get("epoch"), h.get("converged"),
                          h.get("estimate_source")]
        for p in params:
            s = (h.get("parameters") or {}).get(p)
            s = s if isinstance(s, Mapping) else {"mean": s}
            ci = s.get("ci95") if isinstance(s.get("ci95"), (list, tuple)) else [None, None]
            row += [s.get("mean", s.get("value")), ci[0], ci[1]]
        modal = h.get("modal") or {}
        f, z = modal.get("frequency_hz") or [], modal.get("damping_ratio") or []
        for k in range(n_modes):
            row += [f[k] if k < len(f) else None, z[k] if k < len(z) else None]
        rows.append(row)
    return header, rows


def alarms_table(report: Mapping[str, Any], units: Mapping[str, str]
                 ) -> tuple[list[str], list[list[Any]]]:
    """Every alarm (also those before a reset: ``alarm_history``), oldest first."""
    alarms = [a for a in (report.get("alarm_history") or report.get("alarms") or [])
              if isinstance(a, Mapping)]
    header = ["alarm", "quantity", "unit", "state", "direction", "change_rel [%]",
              "change_rel_ci95_low [%]", "change_rel_ci95_high [%]", "reference", "raised_record",
              "raised_utc", "confirmed_record", "cleared_record", "cleared_utc", "message"]
    rows = []
    for a in alarms:
        q = str(a.get("parameter", ""))
        ci = a.get("change_rel_ci95") or [None, None]
        pct = (lambda v: 100 * v if isinstance(v, (int, float)) else None)
        rows.append([a.get("id"), q, ascii_unit(units.get(q) or modal_unit(q)), a.get("state"),
                     a.get("direction"), pct(a.get("change_rel")), pct(ci[0]), pct(ci[1]),
                     a.get("reference"), a.get("raised_index"), utc_text(a.get("raised_time")),
                     a.get("confirmed_index"), a.get("cleared_index"),
                     utc_text(a.get("cleared_time")), a.get("message")])
    return header, rows


def export_csv(what: str, estimate: Mapping[str, Any], report: Mapping[str, Any],
               units: Mapping[str, str]) -> str:
    """The CSV text of one export (``what`` in EXPORTS)."""
    if what == "estimates":
        header, rows = estimates_table(estimate, units)
    elif what == "records":
        header, rows = records_table(report, units)
    elif what == "drift":
        header, rows = drift_table(report, units)
    elif what == "alarms":
        header, rows = alarms_table(report, units)
    else:
        raise ValueError(f"unknown export {what!r}: one of {', '.join(EXPORTS)}")
    return to_csv(header, rows)


__all__ = ["EXPORTS", "export_csv", "ascii_unit", "utc_text"]
