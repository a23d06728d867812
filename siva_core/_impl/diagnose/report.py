"""The self-contained HTML report of a diagnosis: verdict(s) with the model block to add,
the ranking, where the gap lies, the amplitude signatures, and figures - no raw JSON."""
from __future__ import annotations

import base64
import html
import io
import math
from typing import Any, Sequence

import numpy as np
from scipy import signal

from .model_spec import element_block
from .results import Diagnosis
from .units import with_unit
from .where import _explain
from .signatures import damping_change

#: the residual spectra reach this multiple of the highest linear mode (its harmonics)
SPECTRUM_HARMONICS = 3.5

_CSS = """body{font-family:system-ui,sans-serif;max-width:1050px;margin:auto;padding:1em;
line-height:1.45;color:#222}h1{font-size:1.5em}h2{margin-top:1.6em;border-bottom:1px solid #ddd}
table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #ccc;padding:3px 8px;
text-align:right;vertical-align:top}td:first-child,th:first-child{text-align:left}
.verdict{background:#eef6ee;border-left:5px solid #3a3;padding:.6em 1em;margin:.5em 0}
.none{background:#f6f2e8;border-left-color:#c90}.sensor{background:#eef0fa;border-left-color:#36c}
pre{background:#f6f6f6;padding:.6em;white-space:pre-wrap;overflow-wrap:anywhere}
img{max-width:100%;height:auto}.small{color:#555;font-size:.92em}"""


def _png(fig: Any) -> str:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100, bbox_inches="tight")
    plt.close(fig)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _f(x: Any, fmt: str = ".4g") -> str:
    return "–" if x is None or (isinstance(x, float) and not math.isfinite(x)) else \
        format(x, fmt)


def _coeffs(kind: str, coeffs: dict[str, Any], intervals: dict[str, Any] | None = None) -> str:
    parts = []
    for k, v in coeffs.items():
        if v is None:
            continue
        s = f"{k} = {with_unit(kind, k, v)}"
        iv = (intervals or {}).get(k)
        if iv and iv[0] is not None and iv[1] is not None:
            s += f" (95 % {iv[0]:.4g} … {iv[1]:.4g})"
        parts.append(s)
    return ", ".join(parts)


def _figures(diag: Diagnosis, data: dict[str, Any]) -> list[tuple[str, str, str]]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams.update({"font.size": 11})
    figs: list[tuple[str, str, str]] = []
    plots = diag.plots or {"records": []}
    recs = [p for p in plots["records"] if p["role"] == "val"] or plots["records"]
    modes = [m for m in plots.get("modes", []) if m > 0]
    best_label = diag.ranking[0].label() if diag.ranking else ""
    if recs:
        gaps = {e["record"]: e.get("gap") or 0 for e in data["where"]["per_record"]}
        p = max(recs, key=lambda p: gaps.get(p["record"], 0))
        n = p["y"].shape[1]
        fig, axes = plt.subplots(n, 1, figsize=(10, 2.8 * n), sharex=True, squeeze=False)
        for d in range(n):
            ax = axes[d, 0]
            ax.plot(p["t"], p["y"][:, d], "k", lw=0.9, label="measured")
            ax.plot(p["t"], p["nominal"][:, d], "C3", lw=0.9, label="nominal model")
            if p["augmented"] is not None:
                ax.plot(p["t"], p["augmented"][:, d], "C0--", lw=0.9,
                        label=f"with {best_label}")
            ax.set_ylabel(f"{p['quantities'][d]} {diag.structure.dofs[d]}")
            ax.legend(loc="upper right", fontsize=9)
            ax.grid(alpha=0.3)
        axes[-1, 0].set_xlabel("time [s]")
        fig.suptitle(f"validation record {p['record']} (processed)")
        figs.append(("Measured vs nominal vs augmented model",
                     "The validation record with the largest nominal gap.", _png(fig)))

        f_hi = min(p["fs"] / 2, SPECTRUM_HARMONICS * max(modes)) if modes else p["fs"] / 2
        fig, axes = plt.subplots(1, n, figsize=(5.2 * n, 3.6), squeeze=False)
        for d in range(n):
            ax = axes[0, d]
            for lab, x, sty in (("measured", p["y"][:, d], "k"),
                                ("nominal residual", p["nominal"][:, d] - p["y"][:, d], "C3"),
                                ("augmented residual", None if p["augmented"] is None else
                                 p["augmented"][:, d] - p["y"][:, d], "C0")):
                if x is None:
                    continue
                f, P = signal.welch(x, fs=p["fs"], nperseg=min(len(x), 1024))
                m = f <= f_hi
                ax.semilogy(f[m], np.sqrt(P[m]), sty, lw=1.0, label=lab)
            for k, fm in enumerate(modes):
                for h in (1, 2, 3):
                    if h * fm <= f_hi:
                        ax.axvline(h * fm, color="0.6" if h == 1 else "0.85", lw=0.8,
                                   ls=":" if h == 1 else "--")
            ax.set_xlim(0, f_hi)
            ax.set_xlabel("frequency [Hz]")
            ax.set_title(diag.structure.dofs[d])
            ax.legend(fontsize=8)
            ax.grid(alpha=0.3)
        fig.suptitle("residual spectra (Welch amplitude); dotted: linear modes, dashed: "
                     "their 2nd and 3rd harmonics", fontsize=10)
        figs.append(("Residual spectra", f"0 to {f_hi:.3g} Hz: the modes and their harmonics.",
                     _png(fig)))
    sig_modes = [m for m in (diag.signatures or {}).get("modes", []) if m.get("measured")]
    if sig_modes:
        fig, axes = plt.subplots(2, len(sig_modes), figsize=(5.2 * len(sig_modes), 6.4),
                                 squeeze=False)
        for k, e in enumerate(sig_modes):
            for src, sty in (("measured", "ko-"), ("nominal", "C3s--"), ("candidate", "C0^--")):
                cur = e.get(src)
                if not cur or not cur["amplitude"]:
                    continue
                lab = src if src != "candidate" else f"with {best_label}"
                axes[0, k].semilogx(cur["amplitude"], np.asarray(cur["damping_ratio"]) * 100,
                                    sty, ms=4, lw=1, label=lab)
                axes[1, k].semilogx(cur["amplitude"], cur["frequency_hz"], sty, ms=4, lw=1,
                                    label=lab)
            axes[0, k].set_title(f"mode {e['mode']} ({e['linear_frequency_hz']:.3g} Hz), "
                                 f"{e['quantity']} {e['dof']}")
            axes[0, k].set_ylabel("damping ratio [%]")
            axes[1, k].set_ylabel("frequency [Hz]")
            axes[1, k].set_xlabel(f"envelope amplitude ({e['quantity']}, processed)")
            for ax in axes[:, k]:
                ax.grid(alpha=0.3, which="both")
                ax.legend(fontsize=8)
        fig.suptitle("amplitude signatures: damping vs amplitude (top), backbone (bottom)")
        figs.append(("Amplitude signatures", (diag.signatures or {}).get("reading", ""),
                     _png(fig)))
    if diag.ranking:
        fig, ax = plt.subplots(figsize=(8, 0.8 + 0.45 * len(diag.ranking)))
        labels = [c.label() for c in diag.ranking]
        vals = [c.closure if math.isfinite(c.closure) else 0.0 for c in diag.ranking]
        named = {id(c) for c in diag.verdicts}
        colors = ["C2" if id(c) in named else "C7" for c in diag.ranking]
        ax.barh(labels[::-1], vals[::-1], color=colors[::-1])
        ax.axvline(diag.rule.get("closure_min", 0.5), color="k", ls="--", lw=0.8)
        ax.set_xlim(min(-0.2, min(vals) - 0.05), 1.02)
        ax.set_xlabel("closure of the validation gap (1 - gap_after / gap_before)")
        figs.append(("Ranking", "Green: named; dashed: the least closure for a verdict.",
                     _png(fig)))
    return figs


def _table(head: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    esc = html.escape
    return ("<table><tr>" + "".join(f"<th>{esc(h)}</th>" for h in head) + "</tr>"
            + "".join("<tr>" + "".join(f"<td>{esc(c)}</td>" for c in r) + "</tr>"
                      for r in rows) + "</table>")


def measured_here(where: dict[str, Any]) -> str:
    """What these records show, from the numbers of the tables below (the amplitude trend of
    the per-record gaps, the decay windows), so the page never contradicts its tables."""
    parts = [f"the gap {where.get('amplitude_trend', 'is not measured against amplitude')}"]
    win = {k: v for k, v in (where.get("decay") or {}).items() if v is not None}
    if win:
        w = max(win, key=lambda k: win[k])
        parts.append(f"relative to the response it is worst {w} in the decay "
                     + "(" + ", ".join(f"{k} {v:.3g}" for k, v in win.items()) + ")")
    return "Measured here: " + "; ".join(parts) + "."


def html_report(diag: Diagnosis) -> str:
    """A self-contained HTML page (figures embedded as PNG)."""
    esc = html.escape
    data = diag.to_json()
    where = data["where"]
    if diag.verdicts:
        boxes = []
        for n, c in enumerate(diag.verdicts):
            v = c.verdict_json()
            what = (f"sensor fault: <b>{esc(v['kind'])}</b> on <b>{esc(v['channel'])}</b>"
                    if c.category == "sensor" else
                    f"<b>{esc(v['kind'])}</b> between <b>{esc(v['between'][0])}</b> and "
                    f"<b>{esc(v['between'][1])}</b>")
            boxes.append(
                f"<div class='verdict{' sensor' if c.category == 'sensor' else ''}'>"
                f"{'Effect ' + str(n + 1) + ': ' if len(diag.verdicts) > 1 else ''}{what} "
                f"&mdash; closes {100 * c.closure:.1f} % of the validation gap"
                f"{' left by the effects before it' if n else ''}.<br>"
                f"{esc(_coeffs(c.effect.kind, c.coefficients, v['intervals']))}<br>"
                f"<span class='small'>How this effect usually shows: "
                f"{esc(c.effect.describe(c.coefficients))} {esc(measured_here(where))}</span>"
                f"<pre>{esc(element_block(c))}</pre></div>")
        verdict = "".join(boxes)
        hint = ("<p class='small'>Add the block(s) above to the model (or write the whole "
                "model with <code>siva diagnose ... --write-model FILE</code>) and "
                "re-identify.</p>" if any(c.category == "structure" for c in diag.verdicts)
                else "")
    else:
        best = diag.ranking[0] if diag.ranking else None
        verdict = (f"<div class='verdict none'><b>No effect named</b> &mdash; "
                   f"{esc(str(diag.rule.get('reason', '')))}."
                   + (f" Best tried: {esc(best.label())} (closure {best.closure:.2f})."
                      if best else "") + "</div>")
        hint = ""
    limit = diag.rule.get("pulse_reading_limit")
    if limit and diag.verdicts:  # with no verdict it is already in the reason shown
        hint += f"<p class='small'>Not identifiable from these records: {esc(limit['text'])}.</p>"
    rank_rows = [[c.label(), c.category, _f(c.gap_after), _f(c.closure, ".3f"),
                  _coeffs(c.effect.kind, c.coefficients, {k: list(x) for k, x in
                                                          c.intervals.items()}),
                  _f(c.fit_time_s, ".1f")] for c in diag.ranking]
    rec_rows = [[e["record"], e["role"], _f(e["peak_force"]), _f(e.get("gap")),
                 _f(e.get("gap_after"))] for e in where["per_record"]]
    dof_rows = [[d, _f(x)] for d, x in where["per_dof"].items()]
    decay_rows = [[k, _f(v)] for k, v in where["decay"].items()]
    band_rows = [[b, f"{100 * v['share_of_gap']:.1f} %", _f(v["relative_error"])]
                 for b, v in where["frequency_bands"].items()]
    sig_rows = []
    for e in (diag.signatures or {}).get("modes", []):
        for src in ("measured", "nominal", "candidate"):
            cur = e.get(src)
            if cur:
                sig_rows.append([f"mode {e['mode']} ({e['linear_frequency_hz']:.3g} Hz)", src,
                                 _f(cur.get("damping_exponent"), "+.2f"),
                                 _f(damping_change(cur), ".2f"),
                                 _f(100 * cur["frequency_shift"] if cur.get("frequency_shift")
                                    is not None else None, "+.2f"),
                                 _f(cur.get("even_harmonics"), ".3g")])
    imgs = "".join(f"<h3>{esc(t)}</h3><p class='small'>{esc(cap)}</p><img src='{src}' "
                   f"alt='{esc(t)}'>" for t, cap, src in _figures(diag, data))
    timing = ", ".join(f"{k} {v:.1f} s" for k, v in diag.timing.items())
    return f"""<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>siva diagnose: {esc(diag.structure.name)}</title>
<style>{_CSS}</style></head><body>
<h1>Sim-to-real gap of <code>{esc(diag.structure.name)}</code></h1>
{verdict}{hint}
<h2>Where the gap lies</h2>
<p>{esc(_explain(where, None))}</p>
<p class="small">Nominal validation gap {data['nominal']['gap']:.4g} (normalised output
error: 0 = perfect, 1 = as bad as predicting zero); estimated noise floor
{_f(where.get('noise_floor'), '.3g')}. Processing: {esc(str(data['processing']))}.</p>
{_table(['record', 'role', 'peak force [N]', 'nominal gap', 'with best candidate'], rec_rows)}
{_table(['DOF', 'nominal gap'], dof_rows)}
{_table(['part of the decay', 'gap / response energy'], decay_rows)}
{_table(['frequency band', 'share of gap', 'relative error'], band_rows)}
<h2>Amplitude signatures</h2>
<p class="small">Damping exponent: slope of log(damping ratio) vs log(amplitude) (0 viscous,
+1 velocity-squared, +2 cubic damper, −1 dry friction); frequency change over the amplitude
range (backbone: + hardening, − softening); 2f/f: even-harmonic amplitude ratio
(asymmetric laws).</p>
{_table(['mode', 'source', 'damping exponent', 'damping x (largest / smallest amplitude)',
         'frequency change [%]', '2f/f'], sig_rows)}
<h2>Ranking (fitted candidates)</h2>
{_table(['candidate', 'category', 'gap after', 'closure', 'identified (95 %)', 'fit [s]'],
        rank_rows)}
{imgs}
<p class="small">Time: {esc(timing)}. The full result is in the JSON output
(<code>--out FILE</code>).</p>
</body></html>
"""
