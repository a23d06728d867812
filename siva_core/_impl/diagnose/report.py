"""The self-contained HTML report of a diagnosis."""
from __future__ import annotations

import base64
import io
import json
from typing import Any

import numpy as np
from scipy import signal

from .results import Diagnosis


def _png(fig: Any) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=96, bbox_inches="tight")
    import matplotlib.pyplot as plt

    plt.close(fig)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def html_report(diag: Diagnosis) -> str:
    """A self-contained HTML page: verdict, ranking, where, and three embedded figures."""
    import html as _html

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data = diag.to_json()
    plots = diag.plots or {"records": []}
    recs = [p for p in plots["records"] if p["role"] == "val"] or plots["records"]
    figs: list[tuple[str, str]] = []
    if recs:
        gaps = {e["record"]: e.get("gap") or 0 for e in data["where"]["per_record"]}
        p = max(recs, key=lambda p: gaps.get(p["record"], 0))
        n = p["y"].shape[1]
        fig, axes = plt.subplots(n, 1, figsize=(10, 2.6 * n), sharex=True, squeeze=False)
        for d in range(n):
            ax = axes[d, 0]
            ax.plot(p["t"], p["y"][:, d], "k", lw=0.8, label="measured")
            ax.plot(p["t"], p["nominal"][:, d], "C3", lw=0.8, label="nominal model")
            if p["augmented"] is not None:
                ax.plot(p["t"], p["augmented"][:, d], "C0--", lw=0.8,
                        label="with " + (data["ranking"][0]["kind"] if data["ranking"] else ""))
            ax.set_ylabel(f"{p['quantities'][d]} {diag.structure.dofs[d]}")
            ax.legend(loc="upper right", fontsize=8)
        axes[-1, 0].set_xlabel("time [s]")
        fig.suptitle(f"validation record {p['record']} (processed)")
        figs.append(("Measured vs nominal vs augmented model", _png(fig)))

        fig, axes = plt.subplots(1, n, figsize=(5 * n, 3.2), squeeze=False)
        for d in range(n):
            ax = axes[0, d]
            for lab, x, sty in (("measured", p["y"][:, d], "k"),
                                ("nominal residual", p["nominal"][:, d] - p["y"][:, d], "C3"),
                                ("augmented residual", None if p["augmented"] is None else
                                 p["augmented"][:, d] - p["y"][:, d], "C0")):
                if x is None:
                    continue
                f, P = signal.welch(x, fs=p["fs"], nperseg=min(len(x), 1024))
                ax.semilogy(f, np.sqrt(P), sty, lw=0.9, label=lab)
            for m in plots.get("modes", []):
                ax.axvline(m, color="0.7", lw=0.6, ls=":")
            ax.set_xlabel("frequency [Hz]")
            ax.set_title(diag.structure.dofs[d])
            ax.legend(fontsize=8)
        fig.suptitle("residual spectra (Welch amplitude)")
        figs.append(("Residual spectra", _png(fig)))
    if data["ranking"]:
        fig, ax = plt.subplots(figsize=(8, 0.5 + 0.45 * len(data["ranking"])))
        labels = [f"{c['kind']} {c['between'][0]}-{c['between'][1]}" for c in data["ranking"]]
        vals = [c["closure"] or 0.0 for c in data["ranking"]]
        colors = ["C2" if data["verdict"] and i == 0 else "C7" for i in range(len(vals))]
        ax.barh(labels[::-1], vals[::-1], color=colors[::-1])
        ax.axvline(diag.rule.get("closure_min", 0.3), color="k", ls="--", lw=0.8)
        ax.set_xlabel("closure of the validation gap (1 - gap_after / gap_before)")
        figs.append(("Ranking", _png(fig)))

    esc = _html.escape
    v = data["verdict"]
    verdict = (f"<b>{esc(v['kind'])}</b> between <b>{esc(v['between'][0])}</b> and "
               f"<b>{esc(v['between'][1])}</b> &mdash; closure {v['closure']:.2f}<br>"
               f"{esc(v['explanation'])}" if v else
               f"<b>none</b> &mdash; {esc(str(diag.rule.get('reason', '')))}")
    rows = "".join(
        f"<tr><td>{esc(c['kind'])}</td><td>{esc(' - '.join(c['between']))}</td>"
        f"<td>{c['gap_before']:.4g}</td><td>{(c['gap_after'] or float('nan')):.4g}</td>"
        f"<td>{(c['closure'] or float('nan')):.3f}</td>"
        f"<td>{esc(', '.join(f'{k}={x:.4g}' for k, x in c['coefficients'].items() if x is not None))}</td></tr>"
        for c in data["ranking"])
    where = data["where"]
    w_rows = "".join(f"<tr><td>{esc(e['record'])}</td><td>{esc(e['role'])}</td>"
                     f"<td>{e['peak_force']:.4g}</td><td>{(e.get('gap') or float('nan')):.4g}</td>"
                     f"<td>{(e.get('gap_after') or float('nan')):.4g}</td></tr>"
                     for e in where["per_record"])
    imgs = "".join(f"<h3>{esc(t)}</h3><img src='{src}' style='max-width:100%'>" for t, src in figs)
    return f"""<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>siva diagnose: {esc(diag.structure.name)}</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:auto;padding:1em}}
table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:3px 8px;text-align:right}}
td:first-child{{text-align:left}}</style></head><body>
<h1>Sim-to-real gap of <code>{esc(diag.structure.name)}</code></h1>
<p>Verdict: {verdict}</p>
<p>{esc(where['explanation'])}</p>
<p>Nominal validation gap {data['nominal']['gap']:.4g} (normalised output error; estimated
noise floor {(where['noise_floor'] or float('nan')):.3g}); processing: {esc(data['processing'])}.</p>
<h2>Ranking (fitted candidates)</h2>
<table><tr><th>kind</th><th>between</th><th>gap before</th><th>gap after</th><th>closure</th>
<th>coefficients</th></tr>{rows}</table>
<h2>Where the gap lies</h2>
<table><tr><th>record</th><th>role</th><th>peak force</th><th>nominal gap</th>
<th>with best candidate</th></tr>{w_rows}</table>
<pre>{esc(json.dumps({k: where[k] for k in ('per_dof', 'amplitude_trend', 'decay', 'frequency_bands')}, indent=1))}</pre>
{imgs}
<h2>Full result</h2><pre>{esc(json.dumps(data, indent=1))}</pre>
</body></html>
"""
