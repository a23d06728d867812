"""kill -9 at random moments under concurrent uploads, then check that nothing acknowledged
was lost and that every event log replays to the estimate the service published.

One round: start ``siva serve`` on the same data directory, let ``clients`` threads upload
distinct recordings to a few systems (and retry what the previous round left unanswered,
and re-send some acknowledged ones: idempotent retries), and kill -9 the server at a random
moment.  After the last round the server is restarted, trains a little, and is stopped
gracefully.  Then:

- store: every acknowledged (system, id, sha256) is listed by the restarted server;
- log: every acknowledged recording is in its system's event logs (write-ahead);
- replay: ``siva replay`` of each system's log folder - and of every prefix of it, i.e. the
  logs as they were after each crash - gives exactly the estimate of the last snapshot.

Used by tests/reliability/test_crash_rounds.py (slow) and runnable on its own::

    PYTHONPATH=. python tests/reliability/crash_rounds.py --rounds 10 --clients 50
"""
from __future__ import annotations

import argparse
import hashlib
import importlib.util
import json
import random
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # tests/: synthetic.py

SYSTEMS = ("s0", "s1", "s2")
SPEC = {"dofs": ["x"], "mass": {"x": 0.05}, "elements": [
    {"kind": "damper", "between": ["x", "ground"], "params": {"c": "c"}},
    {"kind": "spring", "between": ["x", "ground"], "params": {"k": "k"}}]}
ENV = {"SIVA_CHECKPOINT_EVERY_S": "1", "SIVA_SNAPSHOT_EVERY": "2", "SIVA_REFINE_EVERY_S": "0",
       "SIVA_TORCH_THREADS": "1", "SIVA_LOG_LEVEL": "WARNING"}


def _server_class() -> Any:
    path = HERE.parent / "service" / "conftest.py"
    spec = importlib.util.spec_from_file_location("siva_service_conftest_cr", path)
    assert spec and spec.loader
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.Server


def recording(seed: int) -> bytes:
    """A distinct, valid free decay (k and v0 from the seed)."""
    from synthetic import free_decay

    rnd = random.Random(seed)
    return free_decay(rnd.uniform(0.5, 2.0), 800, 1000.0, m=0.05, k=rnd.uniform(280, 320),
                      c=0.5).to_csv().encode()


@dataclass
class Stats:
    rounds: int = 0
    requests: int = 0
    acked: dict[tuple[str, str], str] = field(default_factory=dict)  # (system, id) -> sha
    duplicates_acked: int = 0
    duplicate_mismatch: int = 0
    unanswered: int = 0
    five_xx: int = 0
    kill_after_s: list[float] = field(default_factory=list)


class _Clients:
    """``n`` upload threads against one server until it dies (or ``stop``)."""

    def __init__(self, base_url: str, n: int, stats: Stats, pending: list[tuple[str, int]],
                 seed: int) -> None:
        self.base_url = base_url
        self.stats = stats
        self.lock = threading.Lock()
        self.pending = pending          # (system, seed) sent but unanswered: retried
        self.stop = threading.Event()
        self.next_seed = seed
        self.by_seed: dict[int, tuple[str, str]] = {}
        self.threads = [threading.Thread(target=self._run, args=(i,), daemon=True)
                        for i in range(n)]

    def _job(self, rnd: random.Random) -> tuple[str, int]:
        with self.lock:
            if self.pending:
                return self.pending.pop()
            if self.by_seed and rnd.random() < 0.1:  # re-send an acknowledged one
                s = rnd.choice(list(self.by_seed))
                return self.by_seed[s][0], s
            self.next_seed += 1
            return rnd.choice(SYSTEMS), self.next_seed

    def _run(self, i: int) -> None:
        rnd = random.Random(self.next_seed * 1000 + i)
        with httpx.Client(base_url=self.base_url, timeout=30) as c:
            while not self.stop.is_set():
                system, seed = self._job(rnd)
                body = recording(seed)
                role = rnd.choice([None, "train", "validation"]) if seed % 5 else "validation"
                try:
                    r = c.post(f"/v1/systems/{system}/recordings",
                               params={"role": role} if role else {}, content=body,
                               headers={"content-type": "text/csv"})
                except httpx.HTTPError:
                    with self.lock:
                        self.pending.append((system, seed))
                        self.stats.unanswered += 1
                    return  # the server is gone: this round is over for this client
                with self.lock:
                    self.stats.requests += 1
                    if r.status_code >= 500:
                        self.stats.five_xx += 1
                    if r.status_code == 409:  # a retry with another random role: stored
                        continue
                    if r.status_code != 202:
                        continue
                    ack = r.json()
                    key = (system, ack["id"])
                    sha = hashlib.sha256(body).hexdigest()
                    if ack["duplicate"]:
                        self.stats.duplicates_acked += 1
                        if self.stats.acked.get(key, sha) != sha:
                            self.stats.duplicate_mismatch += 1
                    self.stats.acked[key] = sha
                    self.by_seed[seed] = (system, ack["id"])

    def start(self) -> None:
        for t in self.threads:
            t.start()

    def join(self, timeout: float) -> None:
        self.stop.set()
        for t in self.threads:
            t.join(timeout)


def run(rounds: int, clients: int, data_dir: Path, *, seed: int = 1,
        max_kill_after_s: float = 5.0, replay_prefixes: bool = True,
        env: dict[str, str] | None = None) -> dict[str, Any]:
    """The experiment; returns the figures (see the module docstring)."""
    from service.storage.eventlog import read_events
    from service.replay.run import log_files, replay

    Server = _server_class()
    rnd = random.Random(seed)
    stats = Stats()
    pending: list[tuple[str, int]] = []
    data_dir.parent.mkdir(parents=True, exist_ok=True)
    srv = Server(data_dir, {**ENV, **(env or {})})
    t_start = time.monotonic()
    for k in range(rounds):
        srv.start()
        with httpx.Client(base_url=srv.base_url, timeout=30) as c:
            for s in SYSTEMS:
                r = c.put(f"/v1/systems/{s}", json={**SPEC, "name": s})
                assert r.status_code in (200, 201), r.text
        cl = _Clients(srv.base_url, clients, stats, pending, seed * 100000 + k * 1000)
        cl.start()
        delay = rnd.uniform(0.5, max_kill_after_s)
        stats.kill_after_s.append(round(delay, 2))
        time.sleep(delay)
        srv.kill()
        cl.join(60)
        stats.rounds += 1
    # the last start: retry what is pending, train a little, stop gracefully
    srv.start()
    cl = _Clients(srv.base_url, min(clients, 5), stats, pending, seed * 100000 + 99000)
    cl.start()
    time.sleep(3.0)
    cl.join(60)
    with httpx.Client(base_url=srv.base_url, timeout=30) as c:
        listed = {(s, m["id"]): m["sha256"] for s in SYSTEMS
                  for m in c.get(f"/v1/systems/{s}/recordings").json()["recordings"]}
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and any(
                c.get(f"/v1/systems/{s}/estimate").json()["epoch"] < 4 for s in SYSTEMS):
            time.sleep(1.0)
    srv.stop()
    bugs = "unhandled error" in srv.log_text()

    lost_store = [k for k, sha in stats.acked.items() if listed.get(k) != sha]
    logged: dict[tuple[str, str], str] = {}
    for s in SYSTEMS:
        for p in sorted((data_dir / "logs" / s).glob("*.mcap")):
            for e in read_events(p):
                if e.topic == "/siva/recording":
                    logged[(s, e.event.id)] = e.event.sha256
    lost_log = [k for k, sha in stats.acked.items() if logged.get(k) != sha]

    replays: list[dict[str, Any]] = []
    for s in SYSTEMS:
        files = log_files(data_dir / "logs" / s)
        prefixes = range(1, len(files) + 1) if replay_prefixes else [len(files)]
        for n in prefixes:
            t0 = time.monotonic()
            try:
                out = replay(files[:n])
            except Exception as exc:  # noqa: BLE001 - reported, counted as a failure
                replays.append({"system": s, "files": n, "error": f"{type(exc).__name__}: {exc}"})
                continue
            cmp = out["replay"]["compared_to_log"]
            replays.append({"system": s, "files": n, "epoch": out["epoch"],
                            "identical": None if cmp is None else cmp["identical"],
                            "max_diff_in_std": None if cmp is None else cmp["max_diff_in_std"],
                            "seconds": round(time.monotonic() - t0, 1)})
    checked = [r for r in replays if r.get("identical") is not None]
    return {
        "rounds": stats.rounds, "clients": clients, "requests": stats.requests,
        "acknowledged": len(stats.acked), "duplicates_acknowledged": stats.duplicates_acked,
        "duplicate_mismatches": stats.duplicate_mismatch, "unanswered_then_retried":
            stats.unanswered, "five_xx": stats.five_xx, "kill_after_s": stats.kill_after_s,
        "lost_from_store": len(lost_store), "lost_from_log": len(lost_log),
        "stored": len(listed), "logged": len(logged),
        "replays": len(replays), "replays_compared": len(checked),
        "replays_identical": sum(bool(r["identical"]) for r in checked),
        "replay_errors": [r for r in replays if "error" in r],
        "replay_mismatches": [r for r in checked if not r["identical"]],
        "server_logged_bug": bugs, "seconds": round(time.monotonic() - t_start, 1),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rounds", type=int, default=10)
    ap.add_argument("--clients", type=int, default=50)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--data-dir", type=Path, default=None)
    ap.add_argument("--no-prefixes", action="store_true")
    ap.add_argument("--refine-every-s", default="0",
                    help="SIVA_REFINE_EVERY_S of the server (0: the refiner is off)")
    a = ap.parse_args()
    d = a.data_dir or Path(tempfile.mkdtemp(prefix="siva-crash-")) / "data"
    res = run(a.rounds, a.clients, d, seed=a.seed, replay_prefixes=not a.no_prefixes,
              env={"SIVA_REFINE_EVERY_S": a.refine_every_s})
    res["data_dir"] = str(d)
    print(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
