"""Clearance/impact: a stop that only engages beyond a gap (loose support, backlash)."""
from ._base import Amplitudes, Effect, register_effect

#: gaps screened, as fractions of the largest deflection the location sees on train records
GAP_FRACTIONS = (0.1, 0.25, 0.45, 0.7)


def _gaps(amp: Amplitudes) -> list[dict[str, float]]:
    return [{"gap": f * amp.d_max} for f in GAP_FRACTIONS]


CLEARANCE = register_effect(Effect(
    name="clearance", kind="clearance", family="clearance/impact",
    explanation=("a clearance (backlash, loose support, contact with a stop): a stiffness "
                 "that engages only beyond a gap, so records and parts of the decay with "
                 "deflections above the gap stiffen abruptly and gain high harmonics, while "
                 "small vibrations never touch it."),
    magnitude="k", positive=frozenset({"k", "gap"}), shape_grid=_gaps,
    start_factors=(0.5, 1.0, 2.0)))
