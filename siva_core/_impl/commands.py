"""`siva identify`: read the model and records, fit SIVA, write the CONTRACT JSON."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from .inputs import read_fit_records
from .recording import Recording
from .structure import Structure


def identify_command(args: argparse.Namespace) -> int:
    structure = Structure.from_file(args.model)
    checked, took = read_fit_records(structure, args.train, args.val,
                                     maps=getattr(args, "map", None),
                                     units=getattr(args, "unit", None),
                                     resample=getattr(args, "resample", False))
    progress = None if args.quiet else _progress
    for line in [*checked.notes, *(str(w) for w in checked.warnings)]:
        _progress(f"note: {line}")
    train, val = checked.train, checked.val
    from .siva import Siva  # torch: only once the records passed the checks (refusals < 1 s)

    held_out = None
    if not val:
        train, val, held_out = hold_out(train)
        _progress(f"no --val: {held_out}")
    est = Siva(structure, processing=args.processing, preset=args.preset, seed=args.seed,
               max_epochs=args.epochs, baselines=not args.no_baselines,
               progress=progress, fit_target=getattr(args, "fit_target", None)).fit(train, val)
    result = est.result_
    if held_out:
        result.notes.append(f"validation held out automatically: {held_out}")
    result.notes.extend(checked.notes)
    if args.report:
        from .report import write_report

        paths = write_report(est, Path(args.report), progress=progress)
        if progress:
            progress(f"report: {sum(p.suffix == '.png' for p in paths)} figures and "
                     f"index.html in {args.report}")
    verdict = result.assessment(model=args.model, train=" ".join(args.train),
                                val=" ".join(args.val) if args.val else None)
    if not args.quiet:
        _progress("\n" + verdict.text())
    out = result.to_json()
    out["assessment"] = verdict.to_json()  # with the commands filled in
    text = json.dumps(out, indent=2)
    if args.out:
        Path(args.out).write_text(text + "\n")
    else:
        sys.stdout.write(text + "\n")
    return 0


def hold_out(train: list[Recording], fraction: float = 0.25
             ) -> tuple[list[Recording], list[Recording], str]:
    """Validation records when the user gave none, and a sentence saying what was done.

    Several records: the last one is held out (SIVA validates on a record it does not fit).
    One record: it is split in time so that the excitation stays in training (a model
    cannot be fitted on the quiet part before a hit): with several hammer hits the last hit
    onwards is held out; with one hit (or none, or a continuous force) the last
    ``fraction`` is held out, moved later if needed so the hit and the first half of what
    follows it train.  A separate validation test is better (another amplitude tests the
    model).
    """
    if len(train) >= 2:
        return train[:-1], train[-1:], (f"validating on {train[-1].name} (held out of the "
                                        f"{len(train)} training records)")
    rec = train[0]
    n = len(rec)
    (cut, stop), why = _split_point(rec, fraction)
    if cut < 64 or stop - cut < 64:
        raise ValueError(f"{rec.name}: {n} samples are too few to hold out part of it for "
                         f"validation; give --val")
    head, tail = rec.slice(0, cut), rec.slice(cut, stop)
    head.name = f"{rec.name}[:{cut}]"
    tail.name = f"{rec.name}[{cut}:{stop if stop < n else ''}]"
    # the validation test predicts the held-out window from the record's start (its hit
    # or initial state): mid-record, the state is only known through integration
    tail.meta["held_out_of"] = (rec.slice(0, stop), float(rec.time[cut]))
    return [head], [tail], (f"validating on {why} of {rec.name} (t >= {rec.time[cut]:.4g} s), "
                            "training on the rest")


def _split_point(rec: Recording, fraction: float) -> tuple[tuple[int, int], str]:
    """Where a single record is split: (first, one past the last) validation sample, and
    how to say it."""
    from .impulse import detect_impulse

    n = len(rec)
    default = int(round(n * (1.0 - fraction)))
    forces = [v for k, v in rec.channels.items() if k.startswith("force_")]
    imp = detect_impulse(np.stack(forces, axis=-1)) if forces else None
    if imp is None:
        return (default, n), f"the last {fraction:.0%}"
    hits = _hits(imp.mask, gap=max(8, int(0.05 * rec.fs)))
    if len(hits) >= 2:
        prev_end, (first, _) = hits[-2][1], hits[-1]
        return (prev_end + (first - prev_end) // 2, n), f"the last of {len(hits)} hits"
    margin = max(8, int(0.01 * rec.fs))
    # one hit: the response decays into the noise, so the last 25 % in time can be noise
    # and hum only, on which no model is judged fairly (measured on the LO-NO records: the
    # last 2 s of a 530 N record are at 1-2 x the noise).  Hold out the last ``fraction``
    # of the part that still holds response, and leave the noise tail out of validation.
    end = informative_end(rec)
    after = imp.last + margin
    if end - after < 128:
        end = n
    cut = max(after + 64, int(round(after + (1.0 - fraction) * (end - after))))
    return (cut, end), (f"the last {fraction:.0%} of the response after the hit (the "
                        f"record is at the noise level after t = {rec.time[end - 1]:.4g} s)"
                        if end < n else f"the last {fraction:.0%} after the hit")


def informative_end(rec: Recording, ratio: float = 4.0) -> int:
    """One past the last sample where some response channel's moving RMS is still
    ``ratio`` x its white-noise level (beyond it the record is mostly noise and hum, which
    a held-out test would count against the model, and which trains nothing)."""
    from .validation import white_noise_sigma

    n = len(rec)
    win = max(16, n // 40)
    end = 0
    for k, x in rec.channels.items():
        if k.startswith("force_"):
            continue
        x = np.asarray(x, dtype=float) - float(np.median(x))
        sigma = white_noise_sigma(x)
        if not sigma > 0:
            return n
        ms = np.convolve(x ** 2, np.ones(win) / win, mode="same")
        loud = np.flatnonzero(ms > (ratio * sigma) ** 2)
        if loud.size:
            end = max(end, int(loud[-1]) + 1)
    return n if end == 0 else min(n, end)


def _hits(mask: np.ndarray, gap: int) -> list[tuple[int, int]]:
    """[(first, last)] sample of each hit: runs of the pulse mask closer than ``gap``
    samples belong to one hit."""
    idx = np.flatnonzero(mask)
    if idx.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(idx) > gap)
    starts = np.r_[idx[0], idx[breaks + 1]]
    ends = np.r_[idx[breaks], idx[-1]]
    return list(zip(starts.tolist(), ends.tolist()))


def _progress(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)
