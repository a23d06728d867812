"""The processing band checked against the fitted nominal model (issue 16).

``Processing.auto`` sets the band from the spectral peaks it finds; the peaks of strongly
damped higher modes (stiffness-proportional damping: a third mode at 3.6 x the first
mode's damping ratio) or of a mode next to a mains line can be missed, and then the band
cuts modes of the structure: their parameters are left unidentified, the nominal fit
cannot follow its own train records, and no candidate can close the gap (measured on the
issue's random scenarios: 12 of the 18 whose band cut a mode were missed, 4 of the 15
others).  The band is chosen again to keep every linear mode of the first nominal fit,
and that fit is used unless it is poor (train cost above ``nominal_poor``) and worse
than the first; when the first fit cannot follow its train records (poor) and does not
show the band holds the structure (``shows_its_modes``: it failed, above
``nominal_widest``, or lacks a mode per DOF, or a mode is cut) the widest band is tried
too and kept when its train cost is lower.  Only for
``processing="auto"``: a chain the caller gives is kept as given."""
from __future__ import annotations

from typing import Sequence

from ..processing import Processing
from ..recording import Recording
from ..structure import Structure
from .nominal import NominalFit, fit_nominal
from .outputs import Progress, _say
from .settings import DiagnoseSettings

#: a mode within this factor of a band edge counts as cut (the band-pass has a 4th-order
#: roll-off: at 1/1.25 of the low-pass corner a mode already loses part of its peak)
EDGE = 1.25
COVER = "the fitted modes"


def cut_modes(modes: Sequence[float], band: tuple[float, float]) -> list[float]:
    """The modes the band (fh, fl) cuts or leaves within ``EDGE`` of an edge."""
    fh, fl = band
    return [f for f in modes if f > fl / EDGE or f < EDGE * fh]


def resolvable(modes: Sequence[float], records: Sequence[Recording]) -> list[float]:
    """The modes with at least 4 cycles in the shortest record: a slower fitted "mode" is
    not one the records can show (fresh seed 13007: a 0.08 Hz one set a 0.04 Hz
    high-pass and the diagnosis failed), so the band never reaches below them."""
    floor_hz = 4.0 / min(float(r.time[-1] - r.time[0]) for r in records)
    return [f for f in modes if f >= floor_hz]


def _modes(structure: Structure, fit: NominalFit) -> list[float]:
    try:
        return [f for f in structure.linear_modes(fit.theta)["frequency_hz"] if f > 0]
    except Exception:  # noqa: BLE001 - no modes, no check
        return []


def shows_its_modes(first: NominalFit, modes: Sequence[float], cut: bool,
                    structure: Structure, settings: DiagnoseSettings) -> bool:
    """A poor nominal fit that still shows the band holds the structure (no widest band
    needed): it has not failed (train cost at most ``nominal_widest``) and has one
    resolvable oscillating mode per DOF, none cut by the band.

    Why: the widest band helps a fit the band keeps from the structure's modes -- a mode
    beyond the band that the fit made overdamped or lost (fresh-style seed 25936: a 3-DOF
    chain in a 14-61 Hz band, the fit 0.37 with one mode; in the widest band 0.044 with
    all three) or a fit that failed outright (17007, 25918).  A fit that places every mode
    of the model inside the band is poor because an effect is missing (LO-NO two:0: 0.114
    with both modes inside); the widest band only adds the effect's harmonics and noise,
    over the LO-NO matrix and 100 development seeds it was kept there once, by 2.5 % on a
    1-DOF (25990, same verdict; docs, branch nomspeed), while it costs a second nominal
    fit with its restarts."""
    return (first.train_cost <= settings.nominal_widest and not cut
            and len(modes) >= len(structure.dofs))


def _covers(records: Sequence[Recording], first: NominalFit | None,
            structure: Structure, proc: Processing, settings: DiagnoseSettings
            ) -> list[tuple[str, tuple[float, float]]]:
    """The bands to try, as ``Processing.auto``'s ``cover`` (lowest, highest) frequency."""
    nyq = min(r.fs for r in records) / 2
    out: list[tuple[str, tuple[float, float]]] = []
    modes = resolvable(_modes(structure, first) if first is not None else [], records)
    cut = bool(modes and proc.bandpass is not None and cut_modes(modes, proc.bandpass))
    if cut:
        out.append((COVER, (min(modes), min(max(modes), 0.4 * nyq))))
    if first is None or first.train_cost > settings.nominal_poor and not shows_its_modes(
            first, modes, cut, structure, settings):
        lowest = min(modes) if modes else 0.0
        out.append(("the widest band", (lowest, 0.4 * nyq)))
    return out


def fit_nominal_in_band(structure: Structure, train: Sequence[Recording],
                        records: Sequence[Recording], proc: Processing,
                        settings: DiagnoseSettings, progress: Progress | None
                        ) -> tuple[Processing, NominalFit]:
    """The nominal fit in ``proc``'s band, and again in a band that keeps the fitted
    model's modes (or the widest band when the fit cannot follow its train records, or
    diverges); returns the (processing, fit) with the lowest train cost."""
    try:
        best: NominalFit | None = fit_nominal(structure, train, proc, settings, progress)
        failure: Exception | None = None
    except ValueError as exc:  # the nominal model diverges from every start in this band
        best, failure = None, exc
    best_proc = proc
    if proc.bandpass is None:  # states given: no band to choose
        if best is None:
            raise failure  # type: ignore[misc]
        return proc, best
    for why, cover in _covers(records, best, structure, proc, settings):
        if why != COVER and best is not None and best.train_cost <= settings.nominal_poor:
            continue  # the band that keeps the modes already fits
        try:
            wide = Processing.auto(list(records), structure.dofs, cover=cover)
        except Exception as exc:  # noqa: BLE001 - keep the first band
            _say(progress, f"band to keep {why}: not usable ({exc})")
            continue
        if wide.bandpass == best_proc.bandpass:
            continue
        try:
            fit = fit_nominal(structure, train, wide, settings, progress)
        except ValueError as exc:
            _say(progress, f"band {wide.bandpass[0]:.3g}-{wide.bandpass[1]:.3g} Hz to keep "
                           f"{why}: nominal fit failed ({exc})")
            continue
        _say(progress, f"band {wide.bandpass[0]:.3g}-{wide.bandpass[1]:.3g} Hz to keep {why}: "
                       f"nominal train cost {fit.train_cost:.4g}"
                       + (f" (was {best.train_cost:.4g})" if best is not None else ""))
        # a band that cuts a fitted mode leaves its parameters unidentified however well
        # the rest fits (a narrower band also holds less noise): the band that keeps the
        # modes is used unless its fit is poor *and* worse; the widest band only when better
        keep = why == COVER and (best is None or fit.train_cost <= max(
            settings.nominal_poor, best.train_cost))
        if best is None or keep or fit.train_cost < best.train_cost:
            best, best_proc = fit, wide
    if best is None:
        raise failure  # type: ignore[misc]
    return best_proc, best
