"""A law that won its swap, moved to the other places (issue 16, branch placeriv).

``swap.member_swaps`` tries, per set member, look-alike laws at its place and its *own*
law at other places, never a new law at a new place.  A member whose place was found
with the wrong law (its stage fitted a cubic damper m2-ground where a linear damper
m3-ground is missing) is then swapped to the right law at the wrong place and named
with confidence (fresh seed 17676: cubic damper m1-m3 + damper m2-ground named, the
pair with damper m3-ground never fitted; the greedy set of three holding both dampers
closed 0.999).  Place and law were chosen in one step each, so the law's place is
re-opened once the law is settled: the winning law is moved (``member_swaps`` with
``moves_only``) as the chosen member's own law was, named only by the same checks
(``accept``: consistent, each member shows, and -- at another place -- a better fit
to all records); the moved sets within ``swap_noise`` x the floor of the named one are
its place rivals (the data cannot separate the places).
"""
from __future__ import annotations

from typing import Any, Sequence

from .outputs import Progress, _say
from .set_fit import SetFit


def swapped_members(chosen: SetFit, win: SetFit) -> list[int]:
    """The structural members of ``win`` whose law differs from ``chosen``'s at the
    same place (a law swap, not a move)."""
    return [k for k, (a, b) in enumerate(zip(chosen.members, win.members))
            if a.category == "structure" and b.category == "structure"
            and a.loc.between == b.loc.between and a.effect.kind != b.effect.kind]


def merge_moved(win: SetFit, best: SetFit | None, moves: Sequence[tuple[int, SetFit]],
                rivals: list[list[dict[str, Any]]], place_rivals: list[list[dict[str, Any]]],
                ks: Sequence[int], tried: list[dict[str, Any]], rule: dict[str, Any],
                progress: Progress | None = None
                ) -> tuple[SetFit, list[list[dict[str, Any]]]]:
    """``best`` (a move of ``win``'s swapped members ``ks`` that passed its checks with a
    lower validation gap, ``swap.swap_rivals``) or ``win``; the members' rivals: the
    swap's, less the moved member's law rivals at the place it left, and the moves
    within the margin (``place_rivals``) as its place rivals."""
    tried += [{"set": s.label(), "closure": float(s.closure), "stopped": bool(s.stopped),
               "moved_after_swap": True} for _, s in moves]
    top = best if best is not None else win
    rule["moved_after_swap"] = {"from": win.label(), "tried": [s.label() for _, s in moves],
                                "named": top.label()}
    _say(progress, f"swapped law moved: {', '.join(s.label() for _, s in moves)}; "
                   f"named {top.label()}")
    out = [list(rv) if best is None or k not in ks else [] for k, rv in enumerate(rivals)]
    while len(out) < len(place_rivals):
        out.append([])
    for k, rv in enumerate(place_rivals):
        if k >= len(top.members):
            continue
        have = {r["candidate"] for r in out[k]} | {top.members[k].label()}
        out[k] += [r for r in rv if r["candidate"] not in have]
    return top, out
