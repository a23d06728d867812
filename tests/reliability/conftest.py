"""Fixtures of the reliability suite: the service suite's real-server fixtures, plus a
small tmpfs for disk-full and read-only experiments.

The service fixtures (a real ``siva serve`` subprocess per server, 5xx-failing clients,
bug-line checks of the server log) are loaded from tests/service/conftest.py by path, so
both suites share one implementation.
"""
from __future__ import annotations

import importlib.util
import os
import subprocess
import uuid
from pathlib import Path
from typing import Any, Callable, Iterator

import pytest

_SERVICE_CONFTEST = Path(__file__).resolve().parents[1] / "service" / "conftest.py"
_spec = importlib.util.spec_from_file_location("siva_service_conftest", _SERVICE_CONFTEST)
assert _spec is not None and _spec.loader is not None
service_fixtures = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(service_fixtures)

# re-exported: pytest finds fixtures by name in this module
make_server = service_fixtures.make_server
server = service_fixtures.server
base_url = service_fixtures.base_url
client = service_fixtures.client
spec_of = service_fixtures.spec_of
oscillator = service_fixtures.oscillator
linear = service_fixtures.linear
poll = service_fixtures.poll
Server = service_fixtures.Server


class Tmpfs:
    """A size-limited tmpfs (root only): fill it to get ENOSPC, remount it read-only."""

    def __init__(self, path: Path, size_mb: int) -> None:
        self.path = path
        self.size_mb = size_mb
        path.mkdir(parents=True, exist_ok=True)
        subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_mb}m", "tmpfs", str(path)],
                       check=True, capture_output=True)
        self._fillers: list[Path] = []
        self._ro = False

    def fill(self) -> int:
        """Write a filler file until the disk is full; returns the bytes written."""
        p = self.path / f".filler-{uuid.uuid4().hex[:6]}"
        self._fillers.append(p)
        n = 0
        block = b"\0" * (1 << 16)
        with open(p, "wb", buffering=0) as fh:
            try:
                while True:
                    n += fh.write(block)
            except OSError:
                pass
            try:  # the last partial block
                while True:
                    n += fh.write(b"\0" * 512)
            except OSError:
                pass
        return n

    def free(self) -> None:
        for p in self._fillers:
            p.unlink(missing_ok=True)
        self._fillers.clear()

    def read_only(self, ro: bool = True) -> None:
        """Read-only for every new open (a read-only bind mount stacked on the tmpfs: a plain
        ``remount,ro`` is refused while the server holds files open for writing)."""
        if ro and not self._ro:
            subprocess.run(["mount", "--bind", str(self.path), str(self.path)], check=True,
                           capture_output=True)
            subprocess.run(["mount", "-o", "remount,bind,ro", str(self.path)], check=True,
                           capture_output=True)
            self._ro = True
        elif not ro and self._ro:
            subprocess.run(["umount", str(self.path)], check=True, capture_output=True)
            self._ro = False

    def unmount(self) -> None:
        subprocess.run(["umount", "-l", str(self.path)], capture_output=True)


@pytest.fixture
def tmpfs(tmp_path: Path) -> Iterator[Callable[[int], Tmpfs]]:
    """Factory of small tmpfs mounts; skips when this machine cannot mount (not root,
    no CAP_SYS_ADMIN) - the store's fault-injection tests cover that case."""
    mounts: list[Tmpfs] = []

    def make(size_mb: int = 64) -> Tmpfs:
        if os.geteuid() != 0:
            pytest.skip("tmpfs mounts need root")
        try:
            m = Tmpfs(tmp_path / f"disk{len(mounts)}", size_mb)
        except (subprocess.CalledProcessError, FileNotFoundError) as exc:
            pytest.skip(f"cannot mount a tmpfs here ({exc})")
        mounts.append(m)
        return m

    yield make
    for m in mounts:
        try:
            m.read_only(False)
        except subprocess.CalledProcessError:
            pass
        m.unmount()


def json_of(r: Any) -> Any:
    try:
        return r.json()
    except ValueError:
        return r.text


#: the 5xx the service answers on purpose: 503 (/healthz: unhealthy), 507 (disk full/read-only)
EXPECTED_5XX = (503, 507)


def _no_unexpected_5xx(response: Any) -> None:
    if response.status_code >= 500 and response.status_code not in EXPECTED_5XX:
        response.read()
        raise AssertionError(f"5xx from {response.request.method} {response.request.url}: "
                             f"{response.status_code} {response.text[:500]}")


def client_for(srv: Any, timeout: float = 60.0) -> Any:
    """An httpx client of ``srv`` that fails the test on any 5xx except 503 and 507."""
    import httpx

    headers = {"Authorization": f"Bearer {srv.token}"} if srv.token else {}
    return httpx.Client(base_url=srv.base_url, headers=headers, timeout=timeout,
                        event_hooks={"response": [_no_unexpected_5xx]})


@pytest.fixture(scope="session")
def lenient_client() -> Callable[..., Any]:
    return client_for
