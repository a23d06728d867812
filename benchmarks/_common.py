"""What every benchmark needs: the project root and the shared reference data."""
from __future__ import annotations

import os
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def data_dir() -> Path:
    """../shared/data from the project root (the README's convention), or $SIVA_SHARED_DATA."""
    env = os.environ.get("SIVA_SHARED_DATA")
    for cand in ([Path(env)] if env else []) + [ROOT.parent / "shared" / "data"]:
        if (cand / "duffing").is_dir():
            return cand
    raise SystemExit("shared data not found (set SIVA_SHARED_DATA)")
