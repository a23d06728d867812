"""What every report figure shares: colours, labels, the Agg figure factory, grid and
unit helpers (one look across the figures)."""
from __future__ import annotations

import math
import re
from typing import Any, Mapping

import numpy as np


LN4 = math.log(4.0)
#: colours used consistently across figures (paper: measured black, Approach I blue/pink band)
COLOURS = {"measured": "black", "band": "#f4a6c0", "I_mean_sim": "tab:blue",
           "approach_I": "tab:green", "approach_II": "tab:orange", "approach_III": "tab:purple",
           "best": "tab:red", "truth": "black"}
LABELS = {"approach_I": "Approach I (mean params)", "approach_II": "Approach II",
          "approach_III": "Approach III", "best": "best"}


def grid(n: int) -> tuple[int, int]:
    ncols = min(3, n) if n != 4 else 2
    return math.ceil(n / ncols), ncols


def subplots(nrows: int, ncols: int, **kw: Any) -> tuple[Any, Any]:
    """A figure on its own Agg canvas: no pyplot, so no global backend or figure registry
    is touched (safe inside a service thread or next to a user's interactive session)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=kw.pop("figsize", None))
    FigureCanvasAgg(fig)
    return fig, fig.subplots(nrows, ncols, **kw)


def unit_of(units: Mapping[str, str], p: str) -> str:
    u = units.get(p, "")
    return f" [{u}]" if u else ""


def file_slug(name: str) -> str:
    stem = re.sub(r"\.(csv|json|npz|mcap)$", "", name, flags=re.I)
    return re.sub(r"[^A-Za-z0-9_-]+", "_", stem).strip("_")[:40] or "record"


def mse(a: np.ndarray, b: np.ndarray) -> float:
    """Mean over time and DOFs of the squared difference (inf when b diverged)."""
    return float(np.mean((a - b) ** 2)) if np.all(np.isfinite(b)) else math.inf
