"""`siva-client`: the service's HTTP API from a shell.

    siva-client register NAME SPEC.toml
    siva-client upload NAME a.csv b.lvm [--role train|validation]
    siva-client upload-folder NAME DIR [--role ...]
    siva-client recordings NAME
    siva-client estimate NAME
    siva-client wait NAME [--for best|converged] [--max-wait S]
    siva-client drift NAME [--watch] [--interval S]
    siva-client drift reset NAME
    siva-client export NAME --what estimates|records|drift|alarms [--out FILE.csv]
    siva-client delete NAME [--yes] [--archive-logs]

``--url`` (or ``SIVA_URL``, default http://127.0.0.1:8000) and ``--token`` (or
``SIVA_API_TOKEN``) select the service.  Every command prints tables or short summaries:
numbers with 4 significant digits, parameter units from the model's element kinds, times
as local wall-clock time (the zone in the header); ``--json`` (any command) prints the
server's JSON instead (``drift --watch --json``: one JSON line per new history entry /
alarm).  ``export`` writes CSV (units in the column names, UTC times) to ``--out`` or
stdout.  ``delete`` also deletes the system's MCAP event logs on the server, or with
``--archive-logs`` moves them to ``<data>/archive/logs/``; it says which.
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
    p.add_argument("--json", action="store_true",
                   help="print the server's JSON instead of tables (any command)")
    sub = p.add_subparsers(dest="command", required=True)

    c = sub.add_parser("register", help="PUT a model spec (TOML or JSON file)")
    c.add_argument("name")
    c.add_argument("spec")

    c = sub.add_parser("upload", help="POST recordings (CSV, JSON, NPZ, MCAP)")
    c.add_argument("name")
    c.add_argument("paths", nargs="+", metavar="PATH")
    c.add_argument("--role", choices=["train", "validation", "val"],
                   help="default: the server's split rule")
    _add_channel_options(c)

    c = sub.add_parser("upload-folder", help="POST every recording file of a folder")
    c.add_argument("name")
    c.add_argument("folder")
    c.add_argument("--role", choices=["train", "validation", "val"],
                   help="default: from train/ and val/ subfolders or 'val*' names")
    _add_channel_options(c)

    c = sub.add_parser("recordings", help="list the stored recordings")
    c.add_argument("name")

    c = sub.add_parser("estimate", help="the current estimate (a table; --json for JSON)")
    c.add_argument("name")
    _json_flag(c)

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
    _json_flag(c)
    c.add_argument("--last", type=int, default=15, help="history rows shown (default 15)")
    c.add_argument("--watch", action="store_true", help="keep polling, show each change")
    c.add_argument("--interval", type=float, default=2.0, help="poll period for --watch [s]")
    c.add_argument("--count", type=int, default=0,
                   help="with --watch: stop after this many polls (0: until Ctrl-C)")

    c = sub.add_parser("export", help="CSV of the estimate, per-record fits, drift history "
                                      "or alarms (units in the column names)")
    c.add_argument("name")
    c.add_argument("--what", choices=EXPORTS, default="estimates",
                   help="estimates (default): the current estimate; records: the per-record "
                        "fits; drift: the published estimates over time; alarms")
    c.add_argument("--out", "-o", metavar="FILE", help="write here (default: stdout)")

    c = sub.add_parser("delete", help="delete a system with its recordings, history and "
                                      "MCAP event logs")
    c.add_argument("name")
    c.add_argument("--yes", action="store_true", help="do not ask for confirmation")
    c.add_argument("--archive-logs", action="store_true",
                   help="move the system's MCAP event logs to <data>/archive/logs/ on the "
                        "server instead of deleting them")
    for c in sub.choices.values():
        if not any(a.dest == "json" for a in c._actions):
            _json_flag(c)
    return p


EXPORTS = ("estimates", "records", "drift", "alarms")


def _add_channel_options(c: argparse.ArgumentParser) -> None:
    """``--map``/``--unit`` as ``siva identify`` has them, sent as the upload's query."""
    c.add_argument("--map", action="append", default=[], metavar="SRC=DST",
                   help="read the file's channel SRC as DST, e.g. --map 'Accel LO=acc_LO' "
                        "(repeatable)")
    c.add_argument("--unit", action="append", default=[], metavar="COL=UNIT",
                   help="the unit a channel was recorded in, e.g. --unit acc_LO=g (repeatable)")


def _json_flag(c: argparse.ArgumentParser) -> None:
    c.add_argument("--json", action="store_true", default=argparse.SUPPRESS,
                   help="the server's JSON instead of a table")


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
    raw = bool(getattr(args, "json", False))

    def show(obj: Any, text: Any) -> None:
        """The server's JSON with --json, else ``text()`` (a table or a summary)."""
        if raw:
            _print(obj, out)
        else:
            out.write(text() + "\n")
            out.flush()

    with SivaClient(args.url, args.token, timeout=args.timeout) as client:
        cmd = args.command
        if cmd == "register":
            ack = client.register(args.name, args.spec)
            show(ack, lambda: render.render_registered(args.name, ack))
        elif cmd == "upload":
            acks = [{"path": p, **client.upload(args.name, p, role=args.role,
                                                channel_map=args.map, units=args.unit)}
                    for p in args.paths]
            show(acks if len(acks) > 1 else acks[0], lambda: render.render_uploads(acks))
        elif cmd == "upload-folder":
            acks = client.upload_folder(args.name, args.folder, role=args.role,
                                        warn=lambda m: print(f"warning: {m}", file=sys.stderr),
                                        channel_map=args.map, units=args.unit)
            show(acks, lambda: render.render_uploads(acks))
        elif cmd == "recordings":
            body = client.recordings(args.name)
            show(body, lambda: render.render_recordings(args.name, body))
        elif cmd == "estimate":
            est = client.estimate(args.name)
            show(est, lambda: render.render_estimate(args.name, est, _units(client, args.name)))
        elif cmd == "wait":
            est = client.wait(args.name, args.until, timeout=args.max_wait)
            show(est, lambda: render.render_estimate(args.name, est, _units(client, args.name)))
        elif cmd == "drift":
            name = _drift_target(args.name)
            if name is None:
                name = args.name[1]
                try:
                    before: dict[str, Any] | None = client.drift(name)
                except SivaClientError:
                    before = None
                after = client.drift_reset(name)
                show(after, lambda: render.render_reset(name, before, after))
            elif args.watch:
                watch_drift(client, name, args.interval, args.count, out, as_json=raw,
                            units=None if raw else _units(client, name), last=args.last)
            else:
                d = client.drift(name)
                show(d, lambda: render.render_drift(name, d, _units(client, name), args.last))
        elif cmd == "export":
            data = client.export(args.name, args.what)
            if args.out:
                with open(args.out, "wb") as f:
                    f.write(data)
                n = max(0, data.count(b"\n") - 1)
                print(f"{args.name}: {args.what} -> {args.out} ({n} row(s), CSV)", file=sys.stderr)
            else:
                out.write(data.decode("utf-8"))
                out.flush()
        elif cmd == "delete":
            what = "archive" if args.archive_logs else "delete"
            if not args.yes and not _confirm(f"delete system {args.name!r} with all its "
                                             f"recordings and history, and {what} its "
                                             "MCAP event logs?"):
                print("siva-client delete: not confirmed (use --yes)", file=sys.stderr)
                return 2
            body = client.delete(args.name, archive_logs=args.archive_logs)
            show(body, lambda: render.render_deleted(args.name, body))
    return 0


def _drift_target(names: list[str]) -> str | None:
    """``drift NAME`` -> NAME; ``drift reset NAME`` -> None (a reset)."""
    if len(names) == 1:
        return names[0]
    if len(names) == 2 and names[0] == "reset":
        return None
    raise SivaClientError(f"drift: expected NAME or 'reset NAME', got {' '.join(names)!r}")


def _units(client: SivaClient, name: str) -> dict[str, str]:
    """Parameter units: the server's ``parameter_units``, else from the system's spec
    (none when it cannot be read)."""
    try:
        info = client.system(name)
    except SivaClientError:
        return {}
    if not isinstance(info, dict):
        return {}
    served = {p: u for p, u in (info.get("parameter_units") or {}).items() if u}
    return {**served, **render.parameter_units(info.get("spec", info))}  # typeset where known


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
