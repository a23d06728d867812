"""`siva diagnose` on the command line."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..progress import FractionProgress
from ..inputs import read_fit_records
from ..structure import Structure
from .model_spec import write_model
from .outputs import _say
from .report import html_report
from .run import diagnose
from .settings import DiagnoseSettings


def diagnose_command(args: argparse.Namespace) -> int:
    """`siva diagnose MODEL --train CSV... --val CSV... [--out FILE] [--html FILE]
    [--write-model FILE] [--budget SECONDS]`."""
    structure = Structure.from_file(args.model)
    checked, _ = read_fit_records(structure, args.train, args.val,
                                  maps=getattr(args, "map", None),
                                  units=getattr(args, "unit", None),
                                  resample=getattr(args, "resample", False))
    train, val = checked.train, checked.val
    quiet = getattr(args, "quiet", False)
    progress = None if quiet else _stderr
    # the stage lines say what is done; the fraction lines when it will be over
    eta = None if quiet else FractionProgress("diagnose", every_s=5.0)
    diag = diagnose(structure, train, val, getattr(args, "processing", "auto"),
                    settings=_settings(args), progress=progress,
                    fraction=eta.update if eta else None)
    if eta:
        eta.update(1.0, force=True)
    text = json.dumps(diag.to_json(), indent=2)
    if getattr(args, "out", None):
        Path(args.out).write_text(text + "\n")
    else:
        sys.stdout.write(text + "\n")
    if getattr(args, "write_model", None):
        if any(c.category == "structure" for c in diag.verdicts):
            Path(args.write_model).write_text(write_model(diag))
            _say(progress, f"augmented model: {args.write_model}")
        else:
            _say(progress, "no structural effect named: --write-model wrote nothing")
    if getattr(args, "html", None):
        Path(args.html).write_text(html_report(diag))
        _say(progress, f"report: {args.html}")
    return 0


def _settings(args: argparse.Namespace) -> DiagnoseSettings:
    """The documented defaults, with ``--budget`` (0 or less: no budget)."""
    budget = getattr(args, "budget", None)
    if budget is None:
        return DiagnoseSettings()
    return DiagnoseSettings(budget_s=budget if budget > 0 else None)


def _stderr(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)
