"""`siva-client`: the service's HTTP API from a shell.

    siva-client register NAME SPEC.toml
    siva-client upload NAME a.csv b.csv [--role train|validation]
    siva-client upload-folder NAME DIR [--role ...]
    siva-client recordings NAME
    siva-client estimate NAME
    siva-client wait NAME [--for best|converged] [--max-wait S]
    siva-client drift NAME [--watch] [--interval S]

``--url`` (or ``SIVA_URL``, default http://127.0.0.1:8000) and ``--token`` (or
``SIVA_API_TOKEN``) select the service.  Output is JSON on stdout (``drift --watch``: one
line per new history entry / alarm); refusals print the server's ``detail`` on stderr and
exit 1, usage errors exit 2.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from typing import Any, Sequence, TextIO

from .client import DEFAULT_URL, SivaClient, SivaClientError


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="siva-client", description="client of a siva service",
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog=__doc__.split("\n\n", 1)[1])
    p.add_argument("--url", default=os.environ.get("SIVA_URL", DEFAULT_URL),
                   help="service base URL (env SIVA_URL; default %(default)s)")
    p.add_argument("--token", default=os.environ.get("SIVA_API_TOKEN"),
                   help="bearer token for writes (env SIVA_API_TOKEN)")
    p.add_argument("--timeout", type=float, default=60.0, help="HTTP timeout [s]")
    sub = p.add_subparsers(dest="command", required=True)

    c = sub.add_parser("register", help="PUT a model spec (TOML or JSON file)")
    c.add_argument("name")
    c.add_argument("spec")

    c = sub.add_parser("upload", help="POST recordings (CSV, JSON, NPZ, MCAP)")
    c.add_argument("name")
    c.add_argument("paths", nargs="+", metavar="PATH")
    c.add_argument("--role", choices=["train", "validation", "val"],
                   help="default: the server's split rule")

    c = sub.add_parser("upload-folder", help="POST every recording file of a folder")
    c.add_argument("name")
    c.add_argument("folder")
    c.add_argument("--role", choices=["train", "validation", "val"],
                   help="default: from train/ and val/ subfolders or 'val*' names")

    c = sub.add_parser("recordings", help="list the stored recordings")
    c.add_argument("name")

    c = sub.add_parser("estimate", help="the current estimate")
    c.add_argument("name")

    c = sub.add_parser("wait", help="wait until the headline estimate is the output-error "
                                    "best (default) or the trainer has converged, then print it")
    c.add_argument("name")
    c.add_argument("--for", dest="until", choices=("best", "converged"), default="best",
                   help="best (default): parameters are the output-error estimate; "
                        "converged: the ensemble has converged (best may still be null)")
    c.add_argument("--max-wait", type=float, default=600.0, help="seconds (default 600)")

    c = sub.add_parser("drift", help="estimate history and drift alarms")
    c.add_argument("name")
    c.add_argument("--watch", action="store_true", help="keep polling, one line per change")
    c.add_argument("--interval", type=float, default=2.0, help="poll period for --watch [s]")
    c.add_argument("--count", type=int, default=0,
                   help="with --watch: stop after this many polls (0: until Ctrl-C)")
    return p


def _print(obj: Any, out: TextIO) -> None:
    out.write(json.dumps(obj, indent=2) + "\n")
    out.flush()


def _history(d: dict[str, Any]) -> list[Any]:
    for key in ("history", "estimates", "snapshots"):
        if isinstance(d.get(key), list):
            return d[key]
    return []


def _alarms(d: dict[str, Any]) -> list[Any]:
    a = d.get("alarms")
    return a if isinstance(a, list) else []


def watch_drift(client: SivaClient, name: str, interval: float, count: int, out: TextIO) -> None:
    """Print each new history entry and alarm as one JSON line, as they appear."""
    seen_h, seen_a, polls = 0, 0, 0
    while True:
        d = client.drift(name)
        hist, alarms = _history(d), _alarms(d)
        if len(hist) < seen_h:  # history was trimmed server-side: resync on its tail
            seen_h = max(0, len(hist) - 1)
        for h in hist[seen_h:]:
            out.write(json.dumps({"event": "estimate", **_compact(h)}) + "\n")
        for a in alarms[seen_a:]:
            out.write(json.dumps({"event": "alarm", **(a if isinstance(a, dict) else {"alarm": a})})
                      + "\n")
        out.flush()
        seen_h, seen_a = len(hist), len(alarms)
        polls += 1
        if count and polls >= count:
            return
        time.sleep(interval)


def _compact(h: Any) -> dict[str, Any]:
    """A history entry with parameters reduced to their means (one readable line)."""
    if not isinstance(h, dict):
        return {"entry": h}
    out = dict(h)
    params = out.get("parameters")
    if isinstance(params, dict):
        out["parameters"] = {k: (v.get("mean") if isinstance(v, dict) else v)
                             for k, v in params.items()}
    return out


def run(args: argparse.Namespace, out: TextIO | None = None) -> int:
    out = out or sys.stdout  # looked up per call: tests and callers may swap sys.stdout
    with SivaClient(args.url, args.token, timeout=args.timeout) as client:
        cmd = args.command
        if cmd == "register":
            _print(client.register(args.name, args.spec), out)
        elif cmd == "upload":
            acks = [{"path": p, **client.upload(args.name, p, role=args.role)} for p in args.paths]
            _print(acks if len(acks) > 1 else acks[0], out)
        elif cmd == "upload-folder":
            _print(client.upload_folder(args.name, args.folder, role=args.role), out)
        elif cmd == "recordings":
            _print(client.recordings(args.name), out)
        elif cmd == "estimate":
            _print(client.estimate(args.name), out)
        elif cmd == "wait":
            _print(client.wait(args.name, args.until, timeout=args.max_wait), out)
        elif cmd == "drift":
            if args.watch:
                watch_drift(client, args.name, args.interval, args.count, out)
            else:
                _print(client.drift(args.name), out)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return run(args)
    except SivaClientError as exc:
        print(f"siva-client {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except TimeoutError as exc:
        print(f"siva-client {args.command}: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
