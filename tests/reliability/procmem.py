"""Memory of a running process from /proc (Linux): the server's growth around a request."""
from __future__ import annotations


def mem_mb(pid: int) -> tuple[float, float]:
    """(current RSS, peak RSS) of a process in MB."""
    vals = {}
    with open(f"/proc/{pid}/status") as fh:
        for line in fh:
            key = line.split(":")[0]
            if key in ("VmRSS", "VmHWM"):
                vals[key] = int(line.split()[1]) / 1024
    return vals["VmRSS"], vals["VmHWM"]


def growth_mb(before: tuple[float, float], after: tuple[float, float]) -> float:
    """How much the process grew in between: to its new peak if it set one, else to its
    current RSS (the peak is a high-water mark since start, so an older peak is ignored)."""
    rss0, hwm0 = before
    rss1, hwm1 = after
    return (hwm1 if hwm1 > hwm0 else rss1) - rss0
