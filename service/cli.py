"""`siva serve` and `siva replay`: argument handling only, the work lives elsewhere.

:data:`COMMANDS` is what the service adds to the ``siva`` program (``siva_cli``); the
library (``siva_core.cli``) never imports this module.
"""
from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import Any

from siva_core.cli import Command

log = logging.getLogger("siva.service")


def _serve_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=8000)
    p.add_argument("--data-dir", default="./siva-data")
    p.add_argument("--demo", action="store_true", help="stream a built-in simulated LO-NO rig")
    p.add_argument("--executor", choices=("threads", "ray"), default=None,
                   help="where trainers run (default: SIVA_EXECUTOR, else threads); "
                        "ray needs pip install '.[ray]' (docs/fleet.md)")
    p.add_argument("--ray-address", default=None,
                   help="the Ray cluster, host:port (default: SIVA_RAY_ADDRESS)")


def _replay_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", help="LOG.mcap")
    p.add_argument("--out", help="write JSON here instead of stdout")
    p.add_argument("--tolerance", type=float, default=None, metavar="STD",
                   help="a replay on another platform is 'reproduced' when every parameter "
                        "mean is within this many published stds of the log's (default 0.1); "
                        "beyond it the verdict is 'differs' and the exit code 1")


#: the service's subcommands of ``siva``
COMMANDS: tuple[Command, ...] = (
    Command("serve", "run the streaming identification service", _serve_args,
            "service.cli:serve_command"),
    Command("replay", "re-run a service MCAP log, print the final estimate", _replay_args,
            "service.cli:replay_command"),
)


def serve_command(args: argparse.Namespace) -> int:
    """Run the service on uvicorn until SIGINT/SIGTERM (workers checkpoint on the way out).

    Settings come from ``SIVA_*`` environment variables; ``--data-dir`` overrides
    ``SIVA_DATA_DIR`` only when given explicitly on the command line or when the variable
    is unset.
    """
    import os

    import uvicorn

    from .api.app import create_app
    from .settings import Settings

    logging.basicConfig(level=os.environ.get("SIVA_LOG_LEVEL", "INFO").upper(),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    data_dir = args.data_dir
    if "SIVA_DATA_DIR" in os.environ and data_dir == "./siva-data":
        data_dir = None  # the parser's default: let the environment decide
    settings = Settings.from_env(data_dir=data_dir, executor=getattr(args, "executor", None),
                                 ray_address=getattr(args, "ray_address", None),
                                 bind_host=args.host)
    if settings.executor == "ray":
        try:
            import ray  # noqa: F401
        except ImportError:
            log.error("--executor ray / SIVA_EXECUTOR=ray needs Ray: pip install '.[ray]'")
            return 2
    if os.environ.get("SIVA_REQUIRE_TOKEN", "0").strip() not in ("", "0") and not settings.api_token:
        log.error("SIVA_REQUIRE_TOKEN is set but SIVA_API_TOKEN is not: refusing to serve an "
                  "open API (set SIVA_API_TOKEN, or SIVA_REQUIRE_TOKEN=0 to run without one)")
        return 2
    app = create_app(settings)
    if getattr(args, "demo", False):
        _start_demo(args.host, args.port, settings)
    log.info("siva serve on http://%s:%d (data dir %s, auth %s)", args.host, args.port,
             Path(settings.data_dir).resolve(), "on" if settings.api_token else "off")
    uvicorn.run(app, host=args.host, port=args.port, log_level="info", access_log=False)
    return 0


def _start_demo(host: str, port: int, settings: Any) -> None:
    """Feed the built-in simulated rig to this server over HTTP, like any client would."""
    from . import demo  # written with the MCAP/replay/demo part of the service

    base = f"http://{'127.0.0.1' if host in ('0.0.0.0', '::') else host}:{port}"
    demo.start_demo(base, token=settings.api_token)  # a daemon thread; waits for /healthz


def replay_command(args: argparse.Namespace) -> int:
    """Re-run a service MCAP log and write the final estimate (shape of GET .../estimate);
    exit 0 when the verdict is identical or reproduced, 1 when it differs."""
    from .replay.run import REPRODUCED_TOLERANCE_IN_STD, write_replay

    tol = getattr(args, "tolerance", None)
    result = write_replay(args.log, getattr(args, "out", None),
                          REPRODUCED_TOLERANCE_IN_STD if tol is None else tol)
    cmp = (result.get("replay") or {}).get("compared_to_log") or {}
    return 1 if cmp.get("verdict") == "differs" else 0
