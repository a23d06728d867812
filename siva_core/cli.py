"""`siva` command line: identify, diagnose, serve, replay (CONTRACT.md).

Each subcommand's work lives with its concern; this module only parses arguments and
dispatches, importing lazily so `siva identify` does not load the web stack.
"""
from __future__ import annotations

import argparse
import sys
from typing import Sequence


def _common_fit_args(p: argparse.ArgumentParser, val_required: bool = True) -> None:
    p.add_argument("model", help="model spec (TOML or JSON)")
    p.add_argument("--train", nargs="+", required=True, metavar="CSV", help="training records")
    p.add_argument("--val", nargs="+", required=val_required, metavar="CSV",
                   help="validation records" + ("" if val_required else
                        " (default: hold out the last training record, or the last 25 %% "
                        "of a single one, and say so)"))
    p.add_argument("--out", help="write JSON here instead of stdout")
    p.add_argument("--seed", type=int, default=42)
    p.add_argument("--processing", default="auto",
                   help="'auto', 'none', 'paper', or a JSON object of Processing settings")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="siva", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("identify", help="identify parameters with SIVA (Approaches I-III)")
    _common_fit_args(p, val_required=False)
    p.add_argument("--epochs", type=int, default=None, help="max epochs (default: until converged)")
    p.add_argument("--preset", choices=["fast", "paper"], default="fast")
    p.add_argument("--fit-target", choices=["output", "equation"], default=None,
                   help="what SIVA's generator is judged on: the output error through the "
                        "processing chain (default; unbiased on measured data) or the paper's "
                        "equation error (default of --preset paper)")
    p.add_argument("--report", metavar="DIR", help="also write the paper's figures here")
    p.add_argument("--no-baselines", action="store_true", help="skip least squares and SINDy")

    p = sub.add_parser("diagnose", help="locate and explain the sim-to-real gap")
    _common_fit_args(p)
    p.add_argument("--html", metavar="FILE", help="also write an HTML report")

    p = sub.add_parser("serve", help="run the streaming identification service")
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=8000)
    p.add_argument("--data-dir", default="./siva-data")
    p.add_argument("--demo", action="store_true", help="stream a built-in simulated LO-NO rig")

    p = sub.add_parser("replay", help="re-run a service MCAP log, print the final estimate")
    p.add_argument("log", help="LOG.mcap")
    p.add_argument("--out", help="write JSON here instead of stdout")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.command == "identify":
        from ._impl.commands import identify_command as run
    elif args.command == "diagnose":
        from ._impl.diagnose import diagnose_command as run
    elif args.command == "serve":
        from service.cli import serve_command as run
    else:
        from service.cli import replay_command as run
    try:
        return int(run(args) or 0)
    except (ValueError, FileNotFoundError) as exc:  # SpecError / RecordingError are ValueErrors
        print(f"siva {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
