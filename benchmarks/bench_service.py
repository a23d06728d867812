"""Service latency: upload-to-acknowledge, and new record to updated estimate.

Starts the real server (``siva serve`` in a subprocess, on a free local port, in a
temporary data dir), registers the Duffing model, then measures with the Python client:

1. upload-to-acknowledge (the 202, sent only once the recording is durably stored:
   parse + validate + fsync'ed store + MCAP log) for a ~1 MB CSV and a ~10 KB CSV,
   p50/p95 over distinct records, while the worker trains in the background;
2. new record to updated estimate: from the POST of a training record to the first
   GET .../estimate whose ``n_recordings`` counts it *and* whose snapshot epoch is past the
   data-set change that brought the record into training (``data.train`` lists it).

Usage: python benchmarks/bench_service.py [--n-large 20] [--n-small 40] [--n-updates 5]
       [--json FILE].  Traffic goes to 127.0.0.1 only; every loop is bounded.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from clients import SivaClient  # noqa: E402

SPEC = ROOT / "examples" / "models" / "duffing.toml"


def oscillator_csv(n: int, fs: float, v0: float, seed: int) -> bytes:
    """A lightly noisy linear free decay with disp, vel, acc (valid for the Duffing model)."""
    k, c, m = 300.0, 0.5, 0.05
    wn = math.sqrt(k / m)
    z = c / (2 * math.sqrt(k * m))
    wd = wn * math.sqrt(1 - z * z)
    t = np.arange(n) / fs
    e = np.exp(-z * wn * t)
    x = v0 / wd * e * np.sin(wd * t)
    v = v0 * e * (np.cos(wd * t) - z * wn / wd * np.sin(wd * t))
    a = -(c * v + k * x) / m
    a = a + 1e-3 * np.abs(a).max() * np.random.default_rng(seed).standard_normal(n)
    rows = np.column_stack([t, x, v, a])
    lines = ["time,disp_x,vel_x,acc_x"] + [",".join(f"{val:.9e}" for val in r) for r in rows]
    return ("\n".join(lines) + "\n").encode()


def pct(xs: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(xs), q))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_server(data: Path, port: int) -> subprocess.Popen:
    env = {**os.environ, "SIVA_TORCH_THREADS": "1", "SIVA_SNAPSHOT_EVERY": "5",
           "SIVA_LOG_LEVEL": "WARNING", "PYTHONPATH": str(ROOT)}
    env.pop("SIVA_API_TOKEN", None)
    return subprocess.Popen([sys.executable, "-m", "siva_cli", "serve", "--port", str(port),
                             "--data-dir", str(data)], env=env, cwd=ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def wait(cond, timeout: float, poll: float = 0.01):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        out = cond()
        if out:
            return out
        time.sleep(poll)
    raise TimeoutError("condition not met in time")


def run(n_large: int, n_small: int, n_updates: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        port = free_port()
        proc = start_server(Path(tmp), port)
        try:
            with SivaClient(f"http://127.0.0.1:{port}", timeout=120) as c:
                wait(c.health, 120, 0.2)
                c.register("bench", SPEC)
                # a small train/validation pair so the worker trains during the measurements
                c.upload("bench", oscillator_csv(1000, 1000.0, 1.0, 0), role="train")
                c.upload("bench", oscillator_csv(1000, 1000.0, 0.6, 1), role="validation")
                wait(lambda: c.estimate("bench")["epoch"] >= 5, 300, 0.1)

                large = [oscillator_csv(15500, 10000.0, 1.0 + 0.01 * i, 100 + i)
                         for i in range(n_large)]
                small = [oscillator_csv(140, 1000.0, 1.0 + 0.01 * i, 500 + i)
                         for i in range(n_small)]
                lat_large, lat_small = [], []
                for body in large:
                    t0 = time.perf_counter()
                    c.upload("bench", body, role="train")
                    lat_large.append(time.perf_counter() - t0)
                for body in small:
                    t0 = time.perf_counter()
                    c.upload("bench", body, role="train")
                    lat_small.append(time.perf_counter() - t0)

                # record -> estimate, on a fresh system so the data set stays small
                c.register("bench2", SPEC)
                c.upload("bench2", oscillator_csv(1000, 1000.0, 1.0, 7), role="train")
                c.upload("bench2", oscillator_csv(1000, 1000.0, 0.6, 8), role="validation")
                wait(lambda: c.estimate("bench2")["epoch"] >= 10, 300, 0.1)
                counted, in_use = [], []
                per_epoch = []
                for i in range(n_updates):
                    before = c.estimate("bench2")
                    n_before = sum(before["n_recordings"].values())
                    body = oscillator_csv(1000, 1000.0, 0.8 + 0.05 * i, 900 + i)
                    t0 = time.perf_counter()
                    rid = c.upload("bench2", body, role="train")["id"]

                    def counted_and_advanced():
                        e = c.estimate("bench2")
                        ok = (sum(e["n_recordings"].values()) == n_before + 1
                              and e["epoch"] > before["epoch"])
                        return e if ok else None

                    wait(counted_and_advanced, 300)
                    counted.append(time.perf_counter() - t0)

                    def trained_on():
                        e = c.estimate("bench2")
                        return e if rid in (e.get("data") or {}).get("train", []) else None

                    e = wait(trained_on, 300)
                    in_use.append(time.perf_counter() - t0)
                    per_epoch.append(e.get("seconds_per_epoch") or float("nan"))
        finally:
            proc.terminate()
            try:
                proc.wait(90)
            except subprocess.TimeoutExpired:
                proc.kill()
    return {
        "upload_ack_s": {
            "csv_1MB": {"bytes": len(large[0]), "n": len(lat_large), "p50": pct(lat_large, 50),
                        "p95": pct(lat_large, 95)},
            "csv_10KB": {"bytes": len(small[0]), "n": len(lat_small), "p50": pct(lat_small, 50),
                         "p95": pct(lat_small, 95)},
        },
        "record_to_estimate_s": {
            "n": n_updates, "snapshot_every": 5,
            "counted_and_epoch_advanced": {"p50": pct(counted, 50), "max": max(counted)},
            "in_training_set_and_published": {"p50": pct(in_use, 50), "max": max(in_use)},
            "seconds_per_epoch": float(np.nanmedian(per_epoch)),
        },
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n-large", type=int, default=20)
    ap.add_argument("--n-small", type=int, default=40)
    ap.add_argument("--n-updates", type=int, default=5)
    ap.add_argument("--json", help="also write the results here")
    args = ap.parse_args()
    res = run(args.n_large, args.n_small, args.n_updates)
    up = res["upload_ack_s"]
    for key, r in up.items():
        print(f"upload -> 202  {key:9s} ({r['bytes'] / 1e6:.2f} MB, n={r['n']}): "
              f"p50 {r['p50'] * 1e3:7.1f} ms   p95 {r['p95'] * 1e3:7.1f} ms")
    r = res["record_to_estimate_s"]
    print(f"record -> estimate (n={r['n']}, snapshot every {r['snapshot_every']} epochs, "
          f"{r['seconds_per_epoch'] * 1e3:.0f} ms/epoch):")
    print(f"  counted + epoch advanced      p50 {r['counted_and_epoch_advanced']['p50']:.2f} s  "
          f"max {r['counted_and_epoch_advanced']['max']:.2f} s")
    print(f"  in training set + published   p50 {r['in_training_set_and_published']['p50']:.2f} s  "
          f"max {r['in_training_set_and_published']['max']:.2f} s")
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
