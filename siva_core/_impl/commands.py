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
    progress = None if args.quiet else _progress
    if args.val:
        val = [Recording.read(p, structure.dofs) for p in args.val]
        held_out = None
    else:
        train, val, held_out = hold_out(train)
        _progress(f"no --val: {held_out}")
    est = Siva(structure, processing=args.processing, preset=args.preset, seed=args.seed,
               max_epochs=args.epochs, baselines=not args.no_baselines,
               progress=progress, fit_target=getattr(args, "fit_target", None)).fit(train, val)
    result = est.result_
    if held_out:
        result.notes.append(f"validation held out automatically: {held_out}")
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


def hold_out(train: list[Recording], fraction: float = 0.25
             ) -> tuple[list[Recording], list[Recording], str]:
    """Validation records when the user gave none, and a sentence saying what was done.

    Several records: the last one is held out (SIVA validates on a record it does not fit).
    One record: its last ``fraction`` is held out, the rest trains, so one test is enough to
    start; a separate validation test is better (a different amplitude tests the model).
    """
    if len(train) >= 2:
        return train[:-1], train[-1:], (f"validating on {train[-1].name} (held out of the "
                                        f"{len(train)} training records)")
    rec = train[0]
    cut = int(round(len(rec) * (1.0 - fraction)))
    if cut < 64 or len(rec) - cut < 64:
        raise ValueError(f"{rec.name}: {len(rec)} samples are too few to hold out "
                         f"{fraction:.0%} for validation; give --val")
    head, tail = rec.slice(0, cut), rec.slice(cut)
    head.name, tail.name = f"{rec.name}[:{cut}]", f"{rec.name}[{cut}:]"
    return [head], [tail], (f"validating on the last {fraction:.0%} of {rec.name} "
                            f"(t >= {rec.time[cut]:.4g} s), training on the rest")


def _progress(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)
