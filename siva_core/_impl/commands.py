"""`siva identify`: read the model and records, fit SIVA, write the CONTRACT JSON."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .recording import Recording
from .siva import Siva
from .structure import Structure


def identify_command(args: argparse.Namespace) -> int:
    structure = Structure.from_file(args.model)
    train = [Recording.read(p, structure.dofs) for p in args.train]
    val = [Recording.read(p, structure.dofs) for p in args.val]
    progress = None if args.quiet else _progress
    est = Siva(structure, processing=args.processing, preset=args.preset, seed=args.seed,
               max_epochs=args.epochs, baselines=not args.no_baselines,
               progress=progress, fit_target=getattr(args, "fit_target", None)).fit(train, val)
    result = est.result_
    if args.report:
        from .report import write_report

        paths = write_report(est, Path(args.report), progress=progress)
        if progress:
            progress(f"report: {sum(p.suffix == '.png' for p in paths)} figures and "
                     f"index.html in {args.report}")
    text = json.dumps(result.to_json(), indent=2)
    if args.out:
        Path(args.out).write_text(text + "\n")
    else:
        sys.stdout.write(text + "\n")
    return 0


def _progress(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)
