"""The sentence an alarm says: the change once, consistent with the alarm's state."""
from __future__ import annotations

from typing import Any, Mapping


def alarm_message(alarm: Mapping[str, Any]) -> str:
    """One sentence that states the change once, consistent with the alarm's state.

    Active: "f1_hz decreased by 1.0 % (95 % CI 0.4-1.6 %) since record 12; confirmed at
    record 15".  Cleared: what was raised, then when and why it was cleared - never the
    state it had before."""
    q = alarm.get("parameter", "?")
    rel, ci = alarm.get("change_rel"), alarm.get("change_rel_ci95")
    noun = "decrease" if alarm.get("direction") == "decrease" else "increase"
    if rel is not None:
        amount = f"{abs(rel) * 100:.1f} %"
        if ci:
            lo, hi = (100 * x for x in ci)
            amount += (f" (95 % CI {min(abs(lo), abs(hi)):.1f}-{max(abs(lo), abs(hi)):.1f} %)"
                       if lo * hi > 0 else f" (95 % CI {lo:+.1f} to {hi:+.1f} %)")
    else:
        amount = ""
    since = alarm.get("change_since_index")
    when = f" since record {since}" if since is not None else ""
    state = alarm.get("state")
    if state == "cleared":
        raised = alarm.get("raised_index")
        what = f"{q}: {noun}" + (f" of {amount}" if amount else "") + when
        how = ("raised at record {r}, confirmed at record {c}" if alarm.get("confirmed_record")
               else "raised at record {r}").format(r=raised, c=alarm.get("confirmed_index"))
        return (f"{what}; {how}; cleared at record {alarm.get('cleared_index')}: "
                f"{alarm.get('cleared_because') or 'cleared'}")
    verb = "decreased" if noun == "decrease" else "increased"
    what = f"{q} {verb}" + (f" by {amount}" if amount else "") + when
    if state == "confirmed":
        return f"{what}; confirmed at record {alarm.get('confirmed_index')}"
    return f"{what}; raised at record {alarm.get('raised_index')}, not yet confirmed"
