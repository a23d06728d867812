"""The library's command-line subcommands: ``identify`` and ``diagnose`` (CONTRACT.md).

The library does not know the service: the ``siva`` program (``siva_cli``) composes these
commands with the service's (``serve``, ``replay``).  Each :class:`Command` only declares
its arguments; its implementation is imported when it runs, so ``siva --help`` loads
neither torch nor the web stack.
"""
from __future__ import annotations

import argparse
import importlib
import sys
from dataclasses import dataclass
from typing import Callable, Sequence


@dataclass(frozen=True)
class Command:
    """One ``siva`` subcommand: its name, help line, arguments, and where it is implemented
    (``"package.module:function"``, called with the parsed arguments, returns an exit code)."""

    name: str
    help: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    target: str

    def load(self) -> Callable[[argparse.Namespace], int | None]:
        module, _, func = self.target.partition(":")
        return getattr(importlib.import_module(module), func)


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
    p.add_argument("--map", action="append", metavar="SRC=DST", default=[],
                   help="read the file's channel SRC as column DST, e.g. --map "
                        "\"Accel LO=acc_LO\" or --map t=time (repeatable)")
    p.add_argument("--unit", action="append", metavar="COL=UNIT", default=[],
                   help="the unit a column was recorded in, converted to SI on reading, e.g. "
                        "--unit acc_LO=g, --unit disp_x=mm (repeatable)")
    p.add_argument("--resample", action="store_true",
                   help="records of different sampling rates: resample to the lowest "
                        "(default: refuse)")


def _identify_args(p: argparse.ArgumentParser) -> None:
    _common_fit_args(p, val_required=False)
    p.add_argument("--epochs", type=int, default=None, help="max epochs (default: until converged)")
    p.add_argument("--preset", choices=["fast", "paper"], default="fast")
    p.add_argument("--fit-target", choices=["output", "equation"], default=None,
                   help="what SIVA's generator is judged on: the output error through the "
                        "processing chain (default; unbiased on measured data) or the paper's "
                        "equation error (default of --preset paper)")
    p.add_argument("--report", metavar="DIR", help="also write the paper's figures here")
    p.add_argument("--no-baselines", action="store_true", help="skip least squares and SINDy")


def _diagnose_args(p: argparse.ArgumentParser) -> None:
    _common_fit_args(p)
    p.add_argument("--html", metavar="FILE", help="also write an HTML report")
    p.add_argument("--write-model", metavar="FILE",
                   help="write the model with the identified effect(s) as a TOML spec")
    p.add_argument("--budget", metavar="SECONDS", type=float, default=None,
                   help="stop opening new work after about this many seconds and name what "
                        "was fitted and checked by then (default 240; 0 = no budget); the "
                        "JSON's rule.budget says whether it was reached and what was not "
                        "searched")


#: the library's own subcommands
COMMANDS: tuple[Command, ...] = (
    Command("identify", "identify parameters with SIVA (Approaches I-III)", _identify_args,
            "siva_core._impl.commands:identify_command"),
    Command("diagnose", "locate and explain the sim-to-real gap", _diagnose_args,
            "siva_core._impl.diagnose:diagnose_command"),
)


def build_parser(commands: Sequence[Command] = COMMANDS,
                 description: str | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="siva", description=description or __doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    for cmd in commands:
        cmd.add_arguments(sub.add_parser(cmd.name, help=cmd.help))
    return parser


def main(argv: Sequence[str] | None = None, commands: Sequence[Command] = COMMANDS,
         description: str | None = None) -> int:
    """Parse ``argv`` against ``commands`` and run the chosen one; bad input (a spec, a
    record, a missing file) is a one-line error and exit code 2, not a traceback."""
    args = build_parser(commands, description).parse_args(argv)
    run = next(c for c in commands if c.name == args.command).load()
    try:
        return int(run(args) or 0)
    except (ValueError, FileNotFoundError) as exc:  # SpecError / RecordingError are ValueErrors
        print(f"siva {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
