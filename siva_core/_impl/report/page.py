"""``index.html``: the verdict first, which estimate to use and why, the parameter and fit
tables, then the figures."""
from __future__ import annotations

import html
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..ensemble import Z95
from .simulations import RecordSims
from .style import LN4


def _fmt(x: Any) -> str:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return html.escape(str(x))
    return f"{v:.5g}" if np.isfinite(v) else str(v)


def _interval(value: float, lo: float, hi: float, unit: str) -> str:
    """"v ± h unit (±r %)": readable where "[lo, hi]" would print the same digits twice."""
    half = 0.5 * (hi - lo)
    unit = "" if unit == "-" else unit  # dimensionless: the unit column says so
    rel = f" (±{100 * half / abs(value):.2g} %)" if value else ""
    return f"{_fmt(value)} ± {float(half):.2g}{(' ' + html.escape(unit)) if unit else ''}{rel}"


def _verdict_banner(verdict: Any) -> str:
    """The validation verdict, first thing on the page (red when rejected)."""
    e = html.escape
    colour = {"accepted": "#e6f4e6", "rejected": "#fbe3e3"}.get(verdict.status, "#fff4d6")
    items = "".join(f"<li>{e(d)}</li>" for d in verdict.details)
    steps = "".join(f"<li><code>{e(s)}</code></li>" if s.startswith("siva ") else
                    f"<li>{e(s)}</li>" for s in verdict.next_steps)
    return (f'<div id="verdict" class="{e(verdict.status)}" style="background:{colour};'
            f'border:1px solid #999;padding:0.6em 1em;margin:1em 0">'
            f"<p><b>{e(verdict.headline)}</b></p>"
            + (f"<ul>{items}</ul>" if items else "")
            + (f"<p>What to try next:</p><ul>{steps}</ul>" if steps else "") + "</div>")


def _recommendation(res: Any, verdict: Any = None) -> str:
    """Which estimate to use and why, in one paragraph (what ``best`` is and how sure)."""
    if verdict is not None and not verdict.usable:
        return ("<p><b><code>best</code> below is what the fit found, not a recommendation"
                "</b>: " + html.escape(verdict.headline) + ".</p>")
    refined = res.best_std is not None
    oe = (res.metrics.get("train") or {}).get("best", {}).get("output_error")
    why = ("<b>Use <code>best</code></b>: the output-error refinement of Approach III, i.e. "
           "the parameters whose simulation, driven by the measured force and passed through "
           "the same processing chain as the measurement, matches the measured displacement "
           "best" + (f" (normalised output error {_fmt(oe)} on the training records)" if oe is not None else "")
           + ". Approaches I and II describe the trained generator and carry the processing "
           "chain's bias on measured data; use them to see how well the data constrain a "
           "parameter, not as the value.")
    if refined:
        why += (" Its 95 % interval is the Gauss-Newton one, inflated for correlated "
                "residuals.")
    else:
        why += (" The refinement did not lower the output error, so <code>best</code> is "
                "Approach III's winner and has no interval of its own.")
    return f"<p>{why}</p>"


def page_html(est: Any, res: Any, names: Sequence[str], truth: np.ndarray | None,
          figures: list[tuple[Path, str]], sims: list[RecordSims], note: str | None) -> str:
    e = html.escape
    units = est.structure.parameter_units() if hasattr(est.structure, "parameter_units") else {}
    verdict = res.assessment(
        train=" ".join(r.name for r in getattr(est, "train_recordings_", [])) or "TRAIN...",
        val=" ".join(r.name for r in getattr(est, "val_recordings_", [])) or None)
    rows = []
    for k, p in enumerate(names):
        u = units.get(p, "")
        I, II = res.approach_I[p], res.approach_II[p]
        if res.best_std is not None and np.isfinite(res.best_std[k]):
            s = float(res.best_std[k])
            use = _interval(float(res.best[k]), res.best[k] - Z95 * s, res.best[k] + Z95 * s, u)
        else:
            use = f"{_fmt(res.best[k])}{(' ' + e(u)) if u and u != '-' else ''} (no interval)"
        cells = [f"{e(p)}", e(u) or "–", f"<b>{use}</b>"]
        if truth is not None:
            cells.append(_fmt(truth[k]))
            err = (f"{100 * (res.best[k] - truth[k]) / abs(truth[k]):+.3f} %"
                   if np.isfinite(truth[k]) and truth[k] != 0 else "–")
            cells.append(err)
        cells += [_interval(I["mean"], I["ci95"][0], I["ci95"][1], u),
                  _interval(II["mean"], II["ci95"][0], II["ci95"][1], u),
                  _fmt(res.approach_III[k])]
        rows.append("<tr>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    head = ["parameter", "unit", ("use this: best ± 95 %" if verdict.usable
                                  else "best ± 95 % (NOT validated: see above)")] + \
        (["exact", "best error"] if truth is not None else []) + \
        ["Approach I mean ± 95 %", "Approach II mean ± 95 %", "Approach III"]
    ptable = (_recommendation(res, verdict) + "<table><tr>" + "".join(f"<th>{e(h)}</th>" for h in head)
              + "</tr>" + "".join(rows) + "</table>")

    mrows = []
    for split in ("train", "validation"):
        for approach, m in (res.metrics.get(split) or {}).items():
            mrows.append(f"<tr><td>{e(split)}</td><td>{e(approach)}</td>"
                         f"<td>{_fmt(m.get('disp_mse_mm2'))}</td>"
                         f"<td>{_fmt(m.get('output_error'))}</td></tr>")
    mtable = ("<table><tr><th>records</th><th>estimate</th><th>displacement MSE [mm²]</th>"
              "<th>output error (NMSE)</th></tr>" + "".join(mrows) + "</table>") if mrows else ""

    disc = res.discriminator or {}
    timing = ", ".join(f"{e(k)} {v:.2f} s" for k, v in res.timing_s.items())
    notes = list(res.notes) + ([note] if note else [])
    figs = "\n".join(
        f'<figure><img src="{e(p.name)}" alt="{e(p.stem)}"><figcaption>{e(c)}</figcaption></figure>'
        for p, c in figures)
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8">
<title>SIVA report - {e(est.structure.name)}</title>
<style>
body {{ font-family: sans-serif; margin: 1.5em; max-width: 1400px; }}
table {{ border-collapse: collapse; margin: 0.6em 0 1.2em; font-size: 0.9em; }}
td, th {{ border: 1px solid #bbb; padding: 3px 8px; text-align: right; }}
th {{ background: #eee; }}
figure {{ margin: 1em 0 2em; }} img {{ max-width: 100%; border: 1px solid #ddd; }}
figcaption {{ color: #333; font-size: 0.9em; }}
</style></head><body>
<h1>SIVA identification: {e(est.structure.name)}</h1>
{_verdict_banner(verdict)}
<p>{len(res.history.get('loss_d', []))} epochs, converged at epoch {e(str(res.converged_epoch))};
Approach I: {len(res.samples_I)} samples; Approach II: {len(res.samples_II)} epochs.
Final discriminator loss {_fmt(disc.get('loss_d'))} (ln 4 = {LN4:.4f}, distance
{_fmt(disc.get('ln4_distance'))}).</p>
<p>Timing: {timing}.</p>
{''.join(f'<p><em>Note: {e(n)}</em></p>' for n in notes)}
<h2>Parameters</h2>
{ptable}
<h2>Displacement fit</h2>
{mtable}
<h2>Figures</h2>
{figs}
</body></html>
"""
