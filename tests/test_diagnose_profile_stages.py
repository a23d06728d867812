"""benchmarks/profile_diagnose_stages.py charges the set stage's parts by function name:
a function of that name in a ``diagnose`` package counts, the same name elsewhere not
(why: ``timing_s['where']`` lumps pair fits, swaps and the nominal-identification check
together, and the profile is what tells them apart)."""
from __future__ import annotations

import cProfile
import importlib.util
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _module(path: Path, name: str):  # noqa: ANN202 - a throwaway module
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    assert spec.loader is not None
    spec.loader.exec_module(mod)
    return mod


BUSY = "def {name}():\n    t = __import__('time').process_time()\n" \
       "    while __import__('time').process_time() - t < 0.05:\n        pass\n"


def test_set_parts_by_name_in_diagnose_only(tmp_path: Path) -> None:
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import profile_diagnose_stages as pds

    (tmp_path / "diagnose").mkdir()
    (tmp_path / "other").mkdir()
    (tmp_path / "diagnose" / "swapmod.py").write_text(BUSY.format(name="swap_members"))
    (tmp_path / "other" / "idmod.py").write_text(BUSY.format(name="check_named"))
    inside = _module(tmp_path / "diagnose" / "swapmod.py", "swapmod_t")
    outside = _module(tmp_path / "other" / "idmod.py", "idmod_t")
    prof = cProfile.Profile(time.process_time)
    prof.enable()
    inside.swap_members()
    outside.check_named()
    prof.disable()
    parts = pds.set_parts_cpu(prof)
    assert set(parts) == set(pds.SET_PARTS.values())
    assert parts["swaps"] >= 0.04
    assert parts["nominal_identification"] == 0.0  # not in a diagnose package
    assert parts["pair_fits"] == 0.0
