"""The spec's ``[channels]`` table: how this system's files name and scale their channels."""
from __future__ import annotations

from typing import Any, Mapping

from .parts import SpecError


def channels_table(section: Any, dofs: list[str]) -> tuple[dict[str, str], dict[str, str]]:
    """The spec's ``[channels]`` table: ``map = {"Accel LO" = "acc_LO"}`` (stored channel
    name -> column name) and ``units = {acc_LO = "g"}`` (declared unit per column)."""
    from ..formats import QUANTITIES, UNIT_FACTORS, split_unit, unit_factor

    if section is None:
        return {}, {}
    if not isinstance(section, Mapping):
        raise SpecError("'channels' must be a table with 'map' and/or 'units'")
    extra = [k for k in section if k not in ("map", "units")]
    if extra:
        raise SpecError(f"channels.{extra[0]}: unknown key (known: map, units)")
    cmap, units = section.get("map", {}) or {}, section.get("units", {}) or {}
    for key, table in (("map", cmap), ("units", units)):
        if not isinstance(table, Mapping) or not all(
                isinstance(k, str) and isinstance(v, str) for k, v in table.items()):
            raise SpecError(f"channels.{key}: must be a table of names to strings")

    def column_ok(col: str) -> bool:
        col = split_unit(col)[0]
        qty, _, dof = col.partition("_")
        return col == "time" or (qty in QUANTITIES and dof in dofs)

    for src, dst in cmap.items():
        if not column_ok(dst):
            raise SpecError(f"channels.map.{src}: {dst!r} is not a column of this model (time, "
                            f"or acc_/vel_/disp_/force_ + one of {dofs})")
    for col, unit in units.items():
        target = split_unit(cmap.get(col, col))[0]
        if not column_ok(target):
            raise SpecError(f"channels.units.{col}: not a column of this model")
        qty = "time" if target == "time" else target.partition("_")[0]
        if unit_factor(unit, qty) is None:
            raise SpecError(f"channels.units.{col}: {unit!r} is not a unit of {qty} (known: "
                            f"{', '.join(UNIT_FACTORS[qty])})")
    return dict(cmap), dict(units)
