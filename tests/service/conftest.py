"""Fixtures that run the REAL service: `python -m siva_cli serve` on a free port.

A subprocess (not an in-process TestClient) so the tests exercise uvicorn, the CLI, the
lifespan and the worker threads exactly as deployed, and so a test can kill -9 it.
Every client fails the test on any 5xx, and every server's log is checked at teardown
for the catch-all handler's "unhandled error" line.
"""
from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
import tomllib
from pathlib import Path
from typing import Any, Callable, Iterator

import httpx
import pytest
from synthetic import free_decay

REPO = Path(__file__).resolve().parents[2]
SHARED_DATA = Path(os.environ.get("SIVA_SHARED_DATA") or REPO.parent / "shared" / "data")
DUFFING = SHARED_DATA / "duffing"
MODELS = REPO / "examples" / "models"

# small, fast defaults for test servers (each can override)
TEST_ENV = {
    "SIVA_TORCH_THREADS": "1",
    "SIVA_SNAPSHOT_EVERY": "2",
    "SIVA_CHECKPOINT_EVERY_S": "2",
    "SIVA_IDLE_SLEEP_S": "0.2",
    "SIVA_LOG_LEVEL": "INFO",
}


#: settings a test run may choose for every server (which executor runs the trainers)
PASS_THROUGH = {"SIVA_EXECUTOR", "SIVA_SHARED_DATA"}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def model_spec(name: str = "duffing") -> dict[str, Any]:
    """A model spec of examples/models as the JSON body of PUT /v1/systems/{name}."""
    with open(MODELS / f"{name}.toml", "rb") as fh:
        return tomllib.load(fh)


def duffing_file(name: str) -> bytes:
    path = DUFFING / name
    if not path.exists():
        pytest.skip(f"shared data not found: {path}")
    return path.read_bytes()


def oscillator_csv(k: float = 300.0, c: float = 0.5, m: float = 0.05, v0: float = 1.0,
                   n: int = 2000, fs: float = 2000.0) -> bytes:
    """A free decay of a linear oscillator (closed form): a valid, cheap CSV record."""
    return free_decay(v0, n, fs, m=m, k=k, c=c).to_csv().encode()


def linear_spec() -> dict[str, Any]:
    return {"name": "linear", "dofs": ["x"], "mass": {"x": 0.05},
            "elements": [{"kind": "damper", "between": ["x", "ground"], "params": {"c": "c"}},
                         {"kind": "spring", "between": ["x", "ground"], "params": {"k": "k"}}]}


def _no_5xx(response: httpx.Response) -> None:
    if response.status_code >= 500:
        response.read()
        raise AssertionError(f"5xx from {response.request.method} {response.request.url}: "
                             f"{response.status_code} {response.text[:500]}")


class Server:
    """One `siva serve` subprocess on a free port with its own data dir and log file."""

    def __init__(self, data_dir: Path, env: dict[str, str] | None = None) -> None:
        self.data_dir = Path(data_dir)
        self.port = free_port()
        self.base_url = f"http://127.0.0.1:{self.port}"
        # the executor under test passes through (`make test-ray`: SIVA_EXECUTOR=ray and
        # the local cluster's SIVA_RAY_ADDRESS); every other SIVA_* setting is the test's
        self.env = {k: v for k, v in os.environ.items()
                    if not k.startswith("SIVA_") or k in PASS_THROUGH or k.startswith("SIVA_RAY_")}
        self.env.update(TEST_ENV)
        self.env.update(env or {})
        self.token = self.env.get("SIVA_API_TOKEN")
        self.log_path = self.data_dir.parent / f"server-{self.port}.log"
        self.proc: subprocess.Popen[bytes] | None = None
        self.logs: list[Path] = []

    def start(self, timeout: float = 120.0) -> "Server":
        self.port = free_port()
        self.base_url = f"http://127.0.0.1:{self.port}"
        self.log_path = self.data_dir.parent / f"server-{self.port}.log"
        self.logs.append(self.log_path)
        self._fh = open(self.log_path, "wb")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "siva_cli", "serve", "--host", "127.0.0.1",
             "--port", str(self.port), "--data-dir", str(self.data_dir)],
            cwd=REPO, env=self.env, stdout=self._fh, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited with {self.proc.returncode}:\n{self.log_tail()}")
            try:
                if httpx.get(self.base_url + "/healthz", timeout=2).status_code == 200:
                    return self
            except httpx.HTTPError:
                pass
            time.sleep(0.2)
        self.kill()
        raise RuntimeError(f"server did not come up in {timeout} s:\n{self.log_tail()}")

    def client(self, token: str | None | bool = True, timeout: float = 60.0) -> httpx.Client:
        """An httpx client; ``token=True`` sends the server's token when it has one."""
        headers = {}
        tok = self.token if token is True else token or None
        if tok:
            headers["Authorization"] = f"Bearer {tok}"
        return httpx.Client(base_url=self.base_url, headers=headers, timeout=timeout,
                            event_hooks={"response": [_no_5xx]})

    def kill(self) -> None:
        """kill -9: no shutdown hook, no final checkpoint."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait(30)
        self._close_log()

    def stop(self) -> None:
        """SIGTERM: the graceful path (workers checkpoint)."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(60)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(30)
        self._close_log()

    def _close_log(self) -> None:
        fh = getattr(self, "_fh", None)
        if fh is not None and not fh.closed:
            fh.close()

    def log_text(self) -> str:
        return "\n".join(p.read_text(errors="replace") for p in self.logs if p.exists())

    def log_tail(self, n: int = 60) -> str:
        return "\n".join(self.log_text().splitlines()[-n:])

    def assert_no_bugs(self) -> None:
        text = self.log_text()
        assert "unhandled error" not in text, f"server logged a bug:\n{self.log_tail(120)}"


@pytest.fixture(scope="module")
def make_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Callable[..., Server]]:
    """Factory: ``make_server(env={...}, data_dir=None)`` starts a server; all are stopped
    (and their logs checked for bugs) when the module is done."""
    servers: list[Server] = []

    def make(env: dict[str, str] | None = None, data_dir: Path | None = None,
             start: bool = True) -> Server:
        d = data_dir or tmp_path_factory.mktemp("siva") / "data"
        s = Server(d, env)
        servers.append(s)
        return s.start() if start else s

    yield make
    for s in servers:
        s.stop()
    for s in servers:
        s.assert_no_bugs()


@pytest.fixture(scope="module")
def server(make_server: Callable[..., Server]) -> Server:
    """A default server (no token, default upload limit)."""
    return make_server()


@pytest.fixture(scope="module")
def base_url(server: Server) -> str:
    return server.base_url


@pytest.fixture
def client(server: Server) -> Iterator[httpx.Client]:
    with server.client() as c:
        yield c


def wait_for(client: httpx.Client, path: str, pred: Callable[[dict[str, Any]], bool],
             timeout: float, every: float = 1.0) -> dict[str, Any]:
    """Poll GET ``path`` until ``pred(json)``; fails with the last body on timeout."""
    deadline = time.monotonic() + timeout
    body: dict[str, Any] = {}
    while time.monotonic() < deadline:
        r = client.get(path)
        assert r.status_code == 200, r.text
        body = r.json()
        if pred(body):
            return body
        time.sleep(every)
    raise AssertionError(f"timeout after {timeout} s waiting on {path}; last body: "
                         f"{ {k: body.get(k) for k in ('epoch', 'converged', 'state', 'error')} }")


# Helpers as fixtures, so test modules never import conftest by name (tests/ has no
# packages, and another folder's conftest.py must not shadow this one).
@pytest.fixture(scope="session")
def spec_of() -> Callable[[str], dict[str, Any]]:
    return model_spec


@pytest.fixture(scope="session")
def duffing() -> Callable[[str], bytes]:
    return duffing_file


@pytest.fixture(scope="session")
def oscillator() -> Callable[..., bytes]:
    return oscillator_csv


@pytest.fixture(scope="session")
def linear() -> dict[str, Any]:
    return linear_spec()


@pytest.fixture(scope="session")
def poll() -> Callable[..., dict[str, Any]]:
    return wait_for


def wait_until(pred: Callable[[], Any], timeout: float, what: str, every: float = 0.2) -> Any:
    """Call ``pred`` until it returns something truthy (returned); fails naming ``what``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        got = pred()
        if got:
            return got
        time.sleep(every)
    raise AssertionError(f"timeout after {timeout} s: {what}")


@pytest.fixture
def until() -> Callable[..., Any]:
    return wait_until
