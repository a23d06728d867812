"""Must-show: the service's running ensemble and headline on the measured LO-NO records.

Starts ``siva serve`` (free port, temporary data dir), registers a model, uploads training
and validation records, and polls GET .../estimate: prints, every poll, the ensemble's and
the headline's relative errors, how many 95 % intervals cover the truth, the validation
verdict, and the seconds since the upload.  Exits when both are final and validated (or
at ``--timeout``).  Also prints the machine's load average (a shared machine).

    python benchmarks/service_lono.py                       # LO-NO, right model
    python benchmarks/service_lono.py --data ../shared/data/gap_examples/cubic_damper_LO_NO \
        --train impact_530N.csv --val impact_37N.csv impact_899N.csv --no-truth
"""
from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

import httpx

REPO = Path(__file__).resolve().parents[1]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--model", default=str(REPO / "examples/models/lono.toml"))
    ap.add_argument("--data", default=str(REPO.parent / "shared/data/lono"))
    ap.add_argument("--train", nargs="+", default=["impact_530N.csv"])
    ap.add_argument("--val", nargs="+", default=["impact_37N.csv", "impact_899N.csv"])
    ap.add_argument("--truth", default="truth.json")
    ap.add_argument("--no-truth", action="store_true")
    ap.add_argument("--timeout", type=float, default=240.0)
    ap.add_argument("--then", nargs="*", default=[], help="more train records uploaded after "
                    "the first estimate is final (one every --every s)")
    ap.add_argument("--every", type=float, default=20.0)
    ap.add_argument("--stream", type=int, default=0, help="simulated LO-NO impacts (service/"
                    "demo.py) streamed as train records after the estimate is final")
    ap.add_argument("--k1-factor", type=float, default=1.0, help="k1 of the streamed records "
                    "x this (0.85: the -15 %% drop of must-show 4; 1: static data)")
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--browser", default=None, help="when final: open the dashboard in "
                    "headless Chromium, print the validation panel, save a screenshot here")
    args = ap.parse_args()
    import signal

    signal.signal(signal.SIGTERM, lambda *_: sys.exit(2))  # so `finally` stops the server
    data = Path(args.data)
    truth = None if args.no_truth else json.loads((data / args.truth).read_text())["truth"]
    port = free_port()
    tmp = tempfile.mkdtemp(prefix="siva-bench-")
    env = {**os.environ, "PYTHONPATH": str(REPO), "SIVA_DATA_DIR": tmp}
    proc = subprocess.Popen([sys.executable, "-m", "siva_cli", "serve", "--port", str(port),
                             "--data-dir", tmp], env=env, stdout=subprocess.DEVNULL,
                            stderr=open(Path(tmp) / "server.log", "w"))
    base = f"http://127.0.0.1:{port}"
    try:
        c = httpx.Client(base_url=base, timeout=30)
        for _ in range(200):
            try:
                if c.get("/healthz").status_code < 500:
                    break
            except httpx.HTTPError:
                time.sleep(0.2)
        spec = tomllib.loads(Path(args.model).read_text())
        r = c.put("/v1/systems/bench", json=spec)
        r.raise_for_status()
        t0 = time.time()
        for role, files in (("train", args.train), ("validation", args.val)):
            for f in files:
                r = c.post("/v1/systems/bench/recordings", params={"role": role},
                           content=(data / f).read_bytes(), headers={"content-type": "text/csv"})
                r.raise_for_status()
        print(f"uploaded at t=0; load average {os.getloadavg()}", flush=True)
        done_at = None
        extra: list = list(args.then)
        if args.stream:
            import numpy as np

            from service.demo import LONO_TRUTH, simulate_impact, to_csv

            rng = np.random.default_rng(args.seed)
            theta = {**LONO_TRUTH, "k1": LONO_TRUTH["k1"] * args.k1_factor}
            for _ in range(args.stream):
                extra.append(to_csv(simulate_impact(theta, float(rng.uniform(200, 900)), rng)))
        sent = 0
        next_up = None
        while time.time() - t0 < args.timeout:
            time.sleep(3)
            e = c.get("/v1/systems/bench/estimate").json()
            t = time.time() - t0
            line = [f"t={t:5.1f}s ep={e.get('epoch')} phase={e.get('phase')} "
                    f"ens={e.get('ensemble_state')} n={e.get('ensemble_samples')} "
                    f"src={e.get('estimate_source')} prov={e.get('provisional')}"]
            ok_e = ok_h = False
            if truth:
                for key in ("ensemble", "parameters"):
                    ps = e.get(key) or {}
                    if not ps:
                        continue
                    errs, cover = [], 0
                    for p, v in truth.items():
                        s = ps.get(p) or {}
                        if s.get("mean") is None:
                            continue
                        errs.append(f"{p}={100 * (s['mean'] - v) / v:+.2f}%")
                        ci = s.get("ci95")
                        cover += bool(ci and ci[0] <= v <= ci[1])
                    line.append(f"  {key}: {' '.join(errs)}  CI covers {cover}/{len(truth)}")
            val = e.get("validation") or {}
            line.append(f"  validation: {val.get('verdict')} T={val.get('T')} p={val.get('p_value')}"
                        f" ens={((val.get('ensemble') or {}).get('verdict'))}"
                        f" agreement={(e.get('agreement') or {}).get('status')}"
                        f" drift={(e.get('drift_status') or {}).get('status')}"
                        f" alarms={[a.get('message') for a in e.get('alarms') or []]}")
            print("\n".join(line), flush=True)
            final = (e.get("ensemble_state") == "final" and e.get("estimate_source") == "best"
                     and val.get("status") == "done")
            if final and done_at is None:
                done_at = t
                print(f"== final and validated {t:.1f} s after the upload; load {os.getloadavg()}",
                      flush=True)
                next_up = time.time()
                if not extra:
                    break
            if done_at is not None and not extra and sent and (
                    e.get("alarms") or time.time() >= (next_up or 0)):
                mon = e.get("monitoring") or {}
                print(f"== streamed {sent}; alarms: {[a.get('message') for a in e.get('alarms') or []]};"
                      f" records fitted {mon.get('records_fitted')}", flush=True)
                break
            if next_up is not None and extra and time.time() >= next_up:
                f = extra.pop(0)
                body = f if isinstance(f, bytes) else Path(f).read_bytes()
                c.post("/v1/systems/bench/recordings", params={"role": "train"},
                       content=body, headers={"content-type": "text/csv"})
                sent += 1
                print(f"-- uploaded streamed record {sent} (k1 x {args.k1_factor})", flush=True)
                next_up = time.time() + args.every
        if args.browser and done_at is not None:
            sys.path.insert(0, str(REPO / "tests"))
            from browser_support import console_errors, full_page_screenshot, start_chromium

            driver, _ = start_chromium()
            try:
                driver.get(base + "/#bench")
                text = ""
                for _ in range(60):
                    text = driver.execute_script(
                        "return document.getElementById('validation').innerText")
                    if "model " in text:
                        break
                    time.sleep(0.5)
                print("== dashboard validation panel (headless Chromium):\n" + text)
                print("== console errors:", console_errors(driver))
                full_page_screenshot(driver, Path(args.browser))
            finally:
                driver.quit()
        metrics = c.get("/metrics").text
        print("== /metrics:\n" + "\n".join(
            line for line in metrics.splitlines()
            if line.startswith(("siva_validation", "siva_model_rejected", "siva_ensemble_final"))))
        print(json.dumps({k: e.get(k) for k in ("validation", "agreement", "drift_status",
                                                 "anchor")}, indent=1)[:4000])
        return 0 if done_at is not None else 1
    finally:
        proc.terminate()
        proc.wait(10)
        print(f"server log: {Path(tmp) / 'server.log'}")


if __name__ == "__main__":
    raise SystemExit(main())
