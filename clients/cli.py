"""`siva-client`: the service's HTTP API from a shell.

    siva-client register NAME SPEC.toml
    siva-client upload NAME a.csv b.lvm [--role train|validation]
    siva-client upload-folder NAME DIR [--role ...]
    siva-client recordings NAME
    siva-client estimate NAME [--json]
    siva-client wait NAME [--for best|converged] [--max-wait S]
    siva-client drift NAME [--watch] [--interval S] [--json]
    siva-client drift reset NAME
    siva-client delete NAME [--yes]

``--url`` (or ``SIVA_URL``, default http://127.0.0.1:8000) and ``--token`` (or
``SIVA_API_TOKEN``) select the service.  ``estimate`` and ``drift`` print tables (4
significant digits, units from the model's element kinds; ``drift --watch`` redraws on a
terminal and appends rows otherwise); ``--json`` gives the server's JSON (``drift --watch
--json``: one JSON line per new history entry / alarm); the other commands print JSON.
``upload-folder`` skips, with a warning on stderr, files that are not recordings.  Refusals
print the server's ``detail`` on stderr and exit 1, usage errors exit 2.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from typing import Any, Sequence, TextIO

from . import render
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

    c = sub.add_parser("estimate", help="the current estimate (a table; --json for JSON)")
    c.add_argument("name")
    c.add_argument("--json", action="store_true", help="the server's JSON instead of a table")

    c = sub.add_parser("wait", help="wait until the headline estimate is the output-error "
                                    "best (default) or the trainer has converged, then print it")
    c.add_argument("name")
    c.add_argument("--for", dest="until", choices=("best", "converged"), default="best",
                   help="best (default): parameters are the output-error estimate; "
                        "converged: the ensemble has converged (best may still be null)")
    c.add_argument("--max-wait", type=float, default=600.0, help="seconds (default 600)")

    c = sub.add_parser("drift", help="estimate history and drift alarms; 'drift reset NAME' "
                                     "forgets the reference and alarms (after a repair)")
    c.add_argument("name", nargs="+", metavar="[reset] NAME")
    c.add_argument("--json", action="store_true", help="the server's JSON instead of tables")
    c.add_argument("--last", type=int, default=15, help="history rows shown (default 15)")
    c.add_argument("--watch", action="store_true", help="keep polling, show each change")
    c.add_argument("--interval", type=float, default=2.0, help="poll period for --watch [s]")
    c.add_argument("--count", type=int, default=0,
                   help="with --watch: stop after this many polls (0: until Ctrl-C)")

    c = sub.add_parser("delete", help="delete a system with its recordings and history")
    c.add_argument("name")
    c.add_argument("--yes", action="store_true", help="do not ask for confirmation")
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


def watch_drift(client: SivaClient, name: str, interval: float, count: int, out: TextIO,
                *, as_json: bool = True, units: dict[str, str] | None = None,
                last: int = 15) -> None:
    """Follow the drift report.  JSON: one line per new history entry and alarm.  Text: on a
    terminal the table is redrawn in place; otherwise new rows (and alarms) are appended."""
    seen_h, seen_a, polls = 0, 0, 0
    widths: list[int] | None = None
    tty = hasattr(out, "isatty") and out.isatty()
    while True:
        d = client.drift(name)
        hist, alarms = _history(d), _alarms(d)
        if len(hist) < seen_h:  # history was trimmed server-side: resync on its tail
            seen_h = max(0, len(hist) - 1)
        if as_json:
            for h in hist[seen_h:]:
                out.write(json.dumps({"event": "estimate", **_compact(h)}) + "\n")
            for a in alarms[seen_a:]:
                out.write(json.dumps({"event": "alarm",
                                      **(a if isinstance(a, dict) else {"alarm": a})}) + "\n")
        elif tty:
            out.write("\x1b[H\x1b[2J" + render.render_drift(name, d, units or {}, last)
                      + f"\n(every {interval:g} s; Ctrl-C to stop)\n")
        else:
            params = render.drift_params(d)
            new_rows = render.drift_rows(hist[seen_h:], params)
            if new_rows and widths is None:
                header = render.drift_header(params, units or {})
                widths = render.stream_widths(header)
                out.write(render.table(header, [], widths) + "\n")
            for r in new_rows:
                out.write(render.row(r, widths) + "\n")
            for a in alarms[seen_a:]:
                if isinstance(a, dict):
                    out.write(f"ALARM {a.get('parameter')}: {a.get('message', '')}\n")
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
            _print(client.upload_folder(args.name, args.folder, role=args.role,
                                        warn=lambda m: print(f"warning: {m}", file=sys.stderr)),
                   out)
        elif cmd == "recordings":
            _print(client.recordings(args.name), out)
        elif cmd == "estimate":
            est = client.estimate(args.name)
            if args.json:
                _print(est, out)
            else:
                out.write(render.render_estimate(args.name, est, _units(client, args.name)) + "\n")
        elif cmd == "wait":
            _print(client.wait(args.name, args.until, timeout=args.max_wait), out)
        elif cmd == "drift":
            name = _drift_target(args.name)
            if name is None:
                _print(client.drift_reset(args.name[1]), out)
            elif args.watch:
                watch_drift(client, name, args.interval, args.count, out, as_json=args.json,
                            units=None if args.json else _units(client, name), last=args.last)
            elif args.json:
                _print(client.drift(name), out)
            else:
                out.write(render.render_drift(name, client.drift(name), _units(client, name),
                                              args.last) + "\n")
        elif cmd == "delete":
            if not args.yes and not _confirm(f"delete system {args.name!r} with all its "
                                             "recordings and history?"):
                print("siva-client delete: not confirmed (use --yes)", file=sys.stderr)
                return 2
            _print(client.delete(args.name), out)
    return 0


def _drift_target(names: list[str]) -> str | None:
    """``drift NAME`` -> NAME; ``drift reset NAME`` -> None (a reset)."""
    if len(names) == 1:
        return names[0]
    if len(names) == 2 and names[0] == "reset":
        return None
    raise SivaClientError(f"drift: expected NAME or 'reset NAME', got {' '.join(names)!r}")


def _units(client: SivaClient, name: str) -> dict[str, str]:
    """Parameter units from the system's spec (none when it cannot be read)."""
    try:
        info = client.system(name)
    except SivaClientError:
        return {}
    return render.parameter_units(info.get("spec", info) if isinstance(info, dict) else None)


def _confirm(question: str) -> bool:
    if not sys.stdin.isatty():
        return False
    return input(f"{question} [y/N] ").strip().lower() in ("y", "yes")


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
