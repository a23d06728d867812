"""The processes of a fleet run and what they cost (for benchmarks/bench_fleet.py).

A fleet run is a ``siva serve`` subprocess and, with ``SIVA_EXECUTOR=ray``, a local
two-node Ray cluster (``scripts/ray-local-cluster.sh`` on a port of its own, so that other
clusters on the machine are neither reused nor stopped).  The meter sums CPU time and
memory per group of processes: the server (the front; with ``threads`` also every
trainer), the Ray trainer hosts (``ray::TrainerHost`` actor processes) and Ray's own
daemons and idle workers.  Why groups rather than one total: the per-system cost of a
trainer and the fixed cost of running Ray at all scale differently in a projection.
"""
from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Iterable

import httpx
import psutil

ROOT = Path(__file__).resolve().parents[1]
CLUSTER_SCRIPT = ROOT / "scripts" / "ray-local-cluster.sh"
#: the process title of a trainer-host actor (service/fleet/ray_host.py ``TrainerHost``)
TRAINER_HOST_MARK = "ray::TrainerHost"
GROUPS = ("server", "trainer_hosts", "ray_daemons")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class ServerProcess:
    """``python -m siva_cli serve`` on a free 127.0.0.1 port, this checkout first on the path."""

    def __init__(self, data_dir: Path, env: dict[str, str], log_path: Path) -> None:
        self.data_dir = data_dir
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.env = {k: v for k, v in os.environ.items() if not k.startswith("SIVA_")}
        self.env.update(env)
        self.env["PYTHONPATH"] = os.pathsep.join([str(ROOT), self.env.get("PYTHONPATH", "")])
        self.log_path = log_path
        self.proc: subprocess.Popen[bytes] | None = None

    @property
    def pid(self) -> int:
        assert self.proc is not None
        return self.proc.pid

    def start(self, timeout: float = 180.0) -> str:
        self._log = open(self.log_path, "wb")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "siva_cli", "serve", "--host", "127.0.0.1",
             "--port", str(self.port), "--data-dir", str(self.data_dir)],
            cwd=ROOT, env=self.env, stdout=self._log, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"siva serve exited with {self.proc.returncode}:\n"
                                   f"{self.log_tail()}")
            try:
                if httpx.get(self.url + "/healthz", timeout=5).status_code in (200, 503):
                    return self.url
            except httpx.HTTPError:
                pass
            time.sleep(0.3)
        self.stop()
        raise RuntimeError(f"siva serve did not answer in {timeout:.0f} s:\n{self.log_tail()}")

    def stop(self, timeout: float = 180.0) -> None:
        """SIGTERM (workers checkpoint, Ray actors are removed), SIGKILL after ``timeout``."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(30)
        if getattr(self, "_log", None) is not None and not self._log.closed:
            self._log.close()

    def log_text(self) -> str:
        return self.log_path.read_text(errors="replace") if self.log_path.exists() else ""

    def log_tail(self, n: int = 40) -> str:
        return "\n".join(self.log_text().splitlines()[-n:])


class LocalRayCluster:
    """A head and a second node on loopback, on a free port, with its own temp dir."""

    def __init__(self, node_cpus: int = 4, port: int | None = None) -> None:
        self.port = port or free_port()
        self.temp_dir = f"/tmp/ray-siva-{self.port}"
        self.address = f"127.0.0.1:{self.port}"
        ray_bin = Path(sys.executable).with_name("ray")
        self.env = {**os.environ, "SIVA_RAY_PORT": str(self.port),
                    "SIVA_RAY_TEMP_DIR": self.temp_dir,
                    "SIVA_RAY_NODE_CPUS": str(node_cpus),
                    # the actors import service.* from this checkout, as the server does
                    "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
        if ray_bin.exists():
            self.env["RAY_BIN"] = str(ray_bin)

    def start(self, timeout: float = 180.0) -> str:
        out = subprocess.run(["bash", str(CLUSTER_SCRIPT), "start"], env=self.env, cwd=ROOT,
                             capture_output=True, text=True, timeout=timeout)
        if out.returncode != 0:
            self.stop()
            raise RuntimeError(f"ray-local-cluster.sh start failed ({out.returncode}): "
                               f"{out.stderr.strip()[-2000:]}")
        return self.address

    def stop(self) -> None:
        """Stop this cluster only (the script kills the processes under its temp dir),
        then remove the temp dir (sessions, logs, spilled objects)."""
        subprocess.run(["bash", str(CLUSTER_SCRIPT), "stop"], env=self.env, cwd=ROOT,
                       capture_output=True, text=True, timeout=120)
        shutil.rmtree(self.temp_dir, ignore_errors=True)

    def processes(self) -> list[psutil.Process]:
        """Every process of this cluster: those naming its temp dir, and their descendants."""
        roots = []
        for p in psutil.process_iter(["cmdline"]):
            cmd = " ".join(p.info.get("cmdline") or [])
            if (self.temp_dir + "/" in cmd or self.temp_dir + " " in cmd
                    or cmd.endswith(self.temp_dir)):
                roots.append(p)
        seen: dict[int, psutil.Process] = {}
        for p in roots:
            for q in [p, *_children(p)]:
                seen.setdefault(q.pid, q)
        return list(seen.values())


def _children(p: psutil.Process) -> list[psutil.Process]:
    try:
        return p.children(recursive=True)
    except psutil.Error:
        return []


def _cmdline(p: psutil.Process) -> str:
    try:
        return " ".join(p.cmdline())
    except psutil.Error:
        return ""


class ProcessMeter:
    """CPU seconds and memory of the server and (with Ray) of the cluster, by group."""

    def __init__(self, server_pid: int, cluster: LocalRayCluster | None = None) -> None:
        self.server = psutil.Process(server_pid)
        self.cluster = cluster

    def groups(self) -> dict[str, list[psutil.Process]]:
        out: dict[str, list[psutil.Process]] = {g: [] for g in GROUPS}
        out["server"] = [self.server, *_children(self.server)]
        mine = {p.pid for p in out["server"]}
        if self.cluster is not None:
            for p in self.cluster.processes():
                if p.pid in mine:
                    continue
                group = "trainer_hosts" if TRAINER_HOST_MARK in _cmdline(p) else "ray_daemons"
                out[group].append(p)
        return out

    def cpu(self) -> dict[int, tuple[str, float]]:
        """Cumulative CPU seconds (user + system) per live process: pid -> (group, s)."""
        out: dict[int, tuple[str, float]] = {}
        for group, procs in self.groups().items():
            for p in procs:
                try:
                    t = p.cpu_times()
                except psutil.Error:
                    continue
                out[p.pid] = (group, t.user + t.system)
        return out

    @staticmethod
    def cpu_delta(start: dict[int, tuple[str, float]],
                  end: dict[int, tuple[str, float]]) -> dict[str, float]:
        """CPU seconds spent per group between two :meth:`cpu` readings (a process born in
        between counts from zero; one that died in between is lost: Ray's short-lived idle
        workers, a small share)."""
        out = {g: 0.0 for g in GROUPS}
        for pid, (group, s) in end.items():
            out[group] += s - (start[pid][1] if pid in start else 0.0)
        return out

    def memory(self, pss: bool = False) -> dict[str, float]:
        """MB per group (RSS; with ``pss`` also the proportional set size, which does not
        count shared pages once per process) and the number of trainer hosts."""
        out: dict[str, float] = {}
        groups = self.groups()
        for group, procs in groups.items():
            rss = pss_sum = 0.0
            for p in procs:
                try:
                    if pss:
                        info = p.memory_full_info()
                        pss_sum += getattr(info, "pss", info.rss)
                        rss += info.rss
                    else:
                        rss += p.memory_info().rss
                except psutil.Error:
                    continue
            out[f"{group}_rss_mb"] = rss / 1e6
            if pss:
                out[f"{group}_pss_mb"] = pss_sum / 1e6
        out["trainer_hosts"] = len(groups["trainer_hosts"])
        return out


def total(mem: dict[str, float], kind: str = "rss") -> float:
    """The sum over the groups of one memory reading (MB)."""
    return sum(mem.get(f"{g}_{kind}_mb", 0.0) for g in GROUPS)


def machine_busy_seconds() -> float:
    """CPU seconds the whole machine spent busy (all users; for the load context)."""
    t = psutil.cpu_times()
    return sum(t) - t.idle - getattr(t, "iowait", 0.0)


def unhandled_errors(log_text: str, marks: Iterable[str] = ("unhandled error", "Traceback")) -> int:
    return sum(log_text.count(m) for m in marks)
