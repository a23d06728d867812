"""Run every ``benchmarks/bench_*.py`` in turn and summarise (``make bench``).

Each benchmark runs as its own process with this interpreter (a crash or a leaked thread
pool in one cannot affect the next), its output streamed as it comes; the summary lists
exit status and wall time per benchmark.  Exit status is 1 when any benchmark failed.

    .venv/bin/python benchmarks/run_all.py [-k PATTERN] [--list] [--timeout S] [-- ARGS]

Arguments after ``--`` are passed to every benchmark (e.g. ``-- --seed 1``).
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def discover(pattern: str | None = None) -> list[Path]:
    """bench_*.py files in this folder, sorted by name, filtered by a substring."""
    files = sorted(HERE.glob("bench_*.py"))
    return [f for f in files if pattern is None or pattern in f.stem]


def run_one(path: Path, extra: list[str], timeout: float | None) -> tuple[int | str, float]:
    """Run one benchmark; returns (exit code or 'timeout', seconds)."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, str(path), *extra], cwd=HERE.parent)
    try:
        rc: int | str = proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()  # only the child this runner started
        proc.wait()
        rc = "timeout"
    return rc, time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    extra: list[str] = []
    if "--" in argv:
        i = argv.index("--")
        argv, extra = argv[:i], argv[i + 1:]
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-k", dest="pattern", help="only benchmarks whose name contains this")
    ap.add_argument("--list", action="store_true", help="list the benchmarks and exit")
    ap.add_argument("--timeout", type=float, default=None, help="seconds per benchmark")
    args = ap.parse_args(argv)

    files = discover(args.pattern)
    if args.list:
        print("\n".join(f.name for f in files))
        return 0
    if not files:
        print("no benchmarks found", file=sys.stderr)
        return 1
    results: list[tuple[str, int | str, float]] = []
    for f in files:
        print(f"\n===== {f.name} =====", flush=True)
        rc, dt = run_one(f, extra, args.timeout)
        results.append((f.name, rc, dt))
        print(f"===== {f.name}: {'ok' if rc == 0 else f'FAILED ({rc})'} in {dt:.1f} s =====",
              flush=True)
    width = max(len(n) for n, _, _ in results)
    print("\nSummary")
    for name, rc, dt in results:
        status = "ok" if rc == 0 else f"FAIL ({rc})"
        print(f"  {name:<{width}}  {status:<14}{dt:>8.1f} s")
    failed = [n for n, rc, _ in results if rc != 0]
    print(f"{len(results) - len(failed)}/{len(results)} ok" + (f"; failed: {', '.join(failed)}"
                                                               if failed else ""))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
