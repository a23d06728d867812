"""Which trainer actor hosts which systems: a small JSON file in the shared data dir.

Why a file: a Ray actor that restarts (its process or node died) is constructed again with
the arguments it was first created with, so it cannot learn from them which systems were
added later.  It reads this file instead; the front is its only writer (atomic writes).
Systems are packed ``per_actor`` to an actor, the least-filled first, so that memory per
process stays bounded and the number of processes grows with the fleet.
"""
from __future__ import annotations

import json
from pathlib import Path

from ..storage.files import atomic_write

FILE = "ray-placement.json"


def read_placement(data_dir: Path) -> dict[str, list[str]]:
    """host id -> the systems it hosts ({} when there is no file yet)."""
    try:
        return {str(k): list(v) for k, v in
                json.loads((Path(data_dir) / FILE).read_text())["hosts"].items()}
    except FileNotFoundError:
        return {}


class Placement:
    """The front's view of the placement file (not thread-safe: the caller locks)."""

    def __init__(self, data_dir: Path, per_actor: int) -> None:
        self.path = Path(data_dir) / FILE
        self.per_actor = per_actor
        self.hosts = read_placement(data_dir)

    def host_of(self, name: str) -> str | None:
        return next((h for h, names in self.hosts.items() if name in names), None)

    def assign(self, name: str) -> str:
        """The host of ``name``, assigning one (and saving) if it has none."""
        host = self.host_of(name)
        if host is not None:
            return host
        open_hosts = [h for h, names in self.hosts.items() if len(names) < self.per_actor]
        if open_hosts:
            host = min(open_hosts, key=lambda h: (len(self.hosts[h]), _index(h)))
        else:
            host = f"h{len(self.hosts)}"
            while host in self.hosts:
                host = f"h{_index(host) + 1}"
        self.hosts.setdefault(host, []).append(name)
        self._save()
        return host

    def remove(self, name: str) -> None:
        host = self.host_of(name)
        if host is not None:
            self.hosts[host].remove(name)
            self._save()

    def _save(self) -> None:
        atomic_write(self.path, json.dumps({"hosts": self.hosts}, indent=1).encode())


def _index(host: str) -> int:
    try:
        return int(host.lstrip("h"))
    except ValueError:
        return 0
