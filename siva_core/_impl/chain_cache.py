"""Memo of what the processing chain derives from a *measured* record.

Refinement, linearisation, replicates, metrics and every diagnosis candidate rebuild their
output-error problem from the same few records, and each build processed the measured
record again; each simulated evaluation re-derived the measured force's filtering, gate
and start index.  Those depend only on the record's samples and the chain's settings, so
they are computed once and served as copies (callers may modify what they get).

Keys hold a digest of the record's time and channel samples (not the object), so a
record modified in place, or another record with the same name, is never served stale.
A small LRU bound keeps memory flat in long-running services.
"""
from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from typing import Any, Callable, Hashable, Iterable

import numpy as np

from .recording import Recording

#: entries kept (each about the size of one processed record)
MAX_ENTRIES = 64

_lock = threading.Lock()
_memo: "OrderedDict[Hashable, Any]" = OrderedDict()


def record_digest(rec: Recording, channels: Iterable[str] | None = None) -> tuple:
    """(name, length, channel names, sha1 of time and the chosen channels' samples)."""
    names = sorted(rec.channels) if channels is None else sorted(channels)
    h = hashlib.sha1()
    for x in (rec.time, *(rec.channels[n] for n in names)):
        a = np.ascontiguousarray(x)
        h.update(str((a.dtype.str, a.shape)).encode())
        h.update(a.data if a.size else b"")
    return (rec.name, len(rec), tuple(sorted(rec.channels)), h.hexdigest())


def memoised(key: Hashable, compute: Callable[[], Any]) -> Any:
    """The stored value for ``key`` (computed and stored on a miss).  The caller copies
    what it hands out: the stored value must stay as computed."""
    with _lock:
        if key in _memo:
            _memo.move_to_end(key)
            return _memo[key]
    value = compute()
    with _lock:
        _memo[key] = value
        _memo.move_to_end(key)
        while len(_memo) > MAX_ENTRIES:
            _memo.popitem(last=False)
    return value


def clear() -> None:
    """Forget everything (tests; memory)."""
    with _lock:
        _memo.clear()
