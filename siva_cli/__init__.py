"""The ``siva`` program: the library's subcommands (identify, diagnose) and the service's
(serve, replay), as CONTRACT.md documents them.

It lives outside both packages so that the library (``siva_core``) never imports the
service; only this composition knows both.  ``python -m siva_cli`` = ``siva``.
"""
from __future__ import annotations

import argparse
import sys
from typing import Sequence

from service.cli import COMMANDS as SERVICE_COMMANDS
from siva_core.cli import COMMANDS as CORE_COMMANDS
from siva_core.cli import Command, build_parser as _build_parser, main as _main

COMMANDS: tuple[Command, ...] = CORE_COMMANDS + SERVICE_COMMANDS

DESCRIPTION = ("siva: streaming system identification for vibrating structures "
               "(SIVA): identify, diagnose, serve, replay.")


def build_parser() -> argparse.ArgumentParser:
    """The full ``siva`` argument parser (all four subcommands)."""
    return _build_parser(COMMANDS, DESCRIPTION)


def main(argv: Sequence[str] | None = None) -> int:
    return _main(argv, COMMANDS, DESCRIPTION)


if __name__ == "__main__":  # pragma: no cover - see __main__.py
    sys.exit(main())
