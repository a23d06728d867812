"""Fixtures of the instrument-file suite: a generated LO-NO-like rig (our own simulator, not
the shared records) and a real ``siva serve`` on a free port."""
from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Iterator

import httpx
import numpy as np
import pytest

from siva_core import Recording, Structure, synthetic_impacts

REPO = Path(__file__).resolve().parents[2]
#: the generating parameters (b1, k1, b2, k2, alpha, beta): a rig of the LO-NO family with
#: values of our own, not the shared reference
THETA = np.array([2.6, 20500.0, 0.9, 2300.0, 1.8e7, 2.0])


@pytest.fixture(scope="session")
def rig() -> Structure:
    return Structure.from_file(REPO / "examples/models/lono.toml")


@pytest.fixture(scope="session")
def impacts(rig) -> list[Recording]:
    """Two hammer tests at 2048 Hz, 4 s: 250 N (train) and 600 N (validation)."""
    return synthetic_impacts(rig, THETA, [250.0, 600.0], dof="NO", fs=2048.0, duration=4.0,
                             seed=11)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def service(tmp_path_factory) -> Iterator[str]:
    """A real ``siva serve`` subprocess (uvicorn, workers) on a free port; its base URL."""
    data = tmp_path_factory.mktemp("siva-instruments")
    port = _free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("SIVA_")}
    env.update({"SIVA_TORCH_THREADS": "1", "SIVA_SNAPSHOT_EVERY": "2",
                "SIVA_IDLE_SLEEP_S": "0.2"})
    log = open(data / "server.log", "wb")
    proc = subprocess.Popen([sys.executable, "-m", "siva_cli", "serve", "--host", "127.0.0.1",
                             "--port", str(port), "--data-dir", str(data / "data")],
                            cwd=REPO, env=env, stdout=log, stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 120
        while True:
            if proc.poll() is not None:
                raise RuntimeError((data / "server.log").read_text())
            try:
                if httpx.get(url + "/healthz", timeout=2).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            if time.monotonic() > deadline:
                raise RuntimeError("server did not start")
            time.sleep(0.2)
        yield url
    finally:
        proc.terminate()
        try:
            proc.wait(60)
        except subprocess.TimeoutExpired:
            proc.kill()
        log.close()
        assert "unhandled error" not in (data / "server.log").read_text(errors="replace")
