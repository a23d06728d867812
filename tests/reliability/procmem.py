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


class PeakRss:
    """Samples a process's RSS (psutil) every ``every`` s in a thread while in the block:
    ``growth_mb`` is the peak above the RSS at entry.  Unlike VmHWM, it sees a peak below
    an older high-water mark too."""

    def __init__(self, pid: int, every: float = 0.005) -> None:
        import psutil

        self.proc = psutil.Process(pid)
        self.every = every
        self.base = self.peak = 0

    def __enter__(self) -> "PeakRss":
        import threading

        self.base = self.peak = self.proc.memory_info().rss
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self.peak = max(self.peak, self.proc.memory_info().rss)
            except Exception:  # noqa: BLE001 - the process ended
                return
            self._stop.wait(self.every)

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()
        try:
            self.peak = max(self.peak, self.proc.memory_info().rss)
        except Exception:  # noqa: BLE001
            pass

    @property
    def growth_mb(self) -> float:
        return (self.peak - self.base) / 2**20
