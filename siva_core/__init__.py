"""siva_core: structural system identification via validation and adaptation (SIVA).

The public API; everything else lives under ``_impl`` and may change.  Names are loaded
on first use (module ``__getattr__``), so ``import siva_core`` (and ``siva --help``) does
not pay for torch, scipy or numba until something needs them.

Model and data
    :class:`Structure` (a model from a spec), :class:`SpecError`, :class:`ElementKind`,
    :func:`register_element`, :data:`ELEMENT_KINDS` (the registry);
    :class:`Recording` (CSV / JSON / NPZ / MCAP / LVM / UFF58 / TDMS / MAT),
    :class:`RecordingError`, :class:`RecordingTooLarge`, :func:`register_format`,
    :func:`sniff_format`, :func:`parse_pairs` (``--map``/``--unit`` text),
    :func:`read_mcap_recording`, :func:`write_mcap_recording`,
    :func:`mcap_bytes`.
Checks before training
    :func:`preflight` (records of one fit) -> :class:`Preflight`, raising
    :class:`PreflightError` (a list of :class:`Problem`); :func:`check_recording` (one
    record: force, sampling vs the modes, clipping, length), :func:`check_rates` (mixed
    sampling rates), :func:`resample_to`, :func:`mode_frequencies`.
Processing
    :class:`Processing` (the chain) -> :class:`States`; :func:`simulated_recording`,
    :func:`central_difference`; :func:`detect_impulse` / :class:`Impulse` (the one rule
    deciding whether a force is a hammer pulse).
Simulation
    :func:`simulate` -> :class:`Simulation`, :func:`auto_substeps`, :func:`stage_force`,
    :func:`adjusted_stage_force`,
    :func:`warmup`; :func:`initial_state_and_force` and :func:`gate_force` (what drives
    the simulation of a measured record).
Identification
    :class:`Siva` (``fit`` returns self; results in ``result_``: :class:`Identification`),
    :class:`SivaSettings`, :class:`SivaTrainer`, :func:`choose_processing`,
    :func:`recommend_best`, :func:`validation_score` (held-out records: does the model
    explain them up to noise?); :class:`Ensemble`, :func:`normal_summary`,
    :func:`effective_sample_size`, :class:`ConvergenceMonitor`;
    output error: :func:`refine` -> :class:`RefineResult`, :func:`output_error`,
    :func:`force_profiled_output_error`, :func:`displacement_mse`, :class:`OutputErrorProblem`,
    :func:`set_pulse_reading` (ablation: the kick at a hammer pulse, docs/perf.md 6.5),
    :func:`set_sample_gain_profiling` (ablation: the gain at the pulse samples, 6.7),
    :func:`linearize` -> :class:`Linearization` (the output error linearised at an anchor),
    :func:`settle` -> :class:`Settled` (the anchor moved to the output-error optimum first);
    baselines: :func:`least_squares`, :func:`sindy`, :class:`FitResult`.
Diagnosis
    :func:`diagnose` -> :class:`Diagnosis`, :class:`DiagnoseSettings`,
    :func:`synthetic_impacts`, :func:`with_effect`, :func:`html_report`;
    :class:`Effect`, :data:`EFFECTS`, :func:`register_effect`.
Reports
    :func:`write_report`; spectra: :func:`fourier_amplitude`, :func:`frequency_band`,
    :func:`cwt`, :func:`dominant_frequency`.
"""
from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

#: public name -> (module under siva_core._impl, attribute there)
_EXPORTS: dict[str, tuple[str, str]] = {}


def _export(module: str, *names: str, **renamed: str) -> None:
    for name in names:
        _EXPORTS[name] = (module, name)
    for public, private in renamed.items():
        _EXPORTS[public] = (module, private)


_export("structure", "Structure", "SpecError")
_export("elements", "ElementKind", "register_element", ELEMENT_KINDS="REGISTRY")
_export("recording", "Recording", "RecordingError")
_export("formats", "RecordingTooLarge", "register_format", "sniff_format", "resolve_format",
        "media_types", "MCAP_MAGIC", "ReadLimits", RECORDING_FORMATS="REGISTRY")
_export("progress", "Eta", "EpochProgress", "FractionProgress")
_export("mcap_recording", "read_mcap_recording", "write_mcap_recording", "mcap_bytes")
_export("processing", "Processing", "States", "simulated_recording", "central_difference")
_export("impulse", "detect_impulse", "Impulse")
_export("simulate", "simulate", "Simulation", "auto_substeps", "stage_force", "warmup",
        "set_measured_force_interp", "adjusted_stage_force")
_export("excitation", "initial_state_and_force", "gate_force")
_export("inputs", "parse_pairs")
_export("preflight", "preflight", "check_recording", "check_rates", "resample_to",
        "mode_frequencies", "Preflight", "PreflightError", "Problem")
_export("siva", "Siva", "Identification", "choose_processing", "recommend_best")
_export("training", "SivaSettings", "SivaTrainer")
_export("ensemble", "Ensemble", "normal_summary", "effective_sample_size")
_export("convergence", "ConvergenceMonitor")
_export("refine", "refine", "RefineResult", "output_error", "displacement_mse",
        "OutputErrorProblem", "force_profiled_output_error")
_export("pulse_kick", "set_pulse_reading")
_export("output_error.sample_gain", "set_sample_gain_profiling")
_export("baselines", "least_squares", "sindy", "FitResult")
_export("validation", "validation_score")
_export("linearized", "linearize", "Linearization", "settle", "Settled", "gauss_newton_step")
_export("diagnose", "diagnose", "Diagnosis", "DiagnoseSettings", "synthetic_impacts",
        "with_effect", "html_report")
_export("effects", "Effect", "EFFECTS", "register_effect")
_export("report", "write_report")
_export("spectra", "fourier_amplitude", "frequency_band", "cwt", "dominant_frequency")

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    try:
        module, attr = _EXPORTS[name]
    except KeyError:
        raise AttributeError(f"module 'siva_core' has no attribute {name!r}") from None
    value = getattr(importlib.import_module(f"{__name__}._impl.{module}"), attr)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


if TYPE_CHECKING:  # static analysers and IDEs see the real objects (tests check the lists match)
    from ._impl.baselines import FitResult, least_squares, sindy
    from ._impl.convergence import ConvergenceMonitor
    from ._impl.diagnose import (DiagnoseSettings, Diagnosis, diagnose, html_report,
                                 synthetic_impacts, with_effect)
    from ._impl.effects import EFFECTS, Effect, register_effect
    from ._impl.elements import REGISTRY as ELEMENT_KINDS
    from ._impl.elements import ElementKind, register_element
    from ._impl.ensemble import Ensemble, effective_sample_size, normal_summary
    from ._impl.excitation import gate_force, initial_state_and_force
    from ._impl.impulse import Impulse, detect_impulse
    from ._impl.mcap_recording import mcap_bytes, read_mcap_recording, write_mcap_recording
    from ._impl.processing import Processing, States, central_difference, simulated_recording
    from ._impl.recording import Recording, RecordingError
    from ._impl.formats import REGISTRY as RECORDING_FORMATS
    from ._impl.formats import (MCAP_MAGIC, ReadLimits, RecordingTooLarge, media_types,
                                register_format, resolve_format, sniff_format)
    from ._impl.inputs import parse_pairs
    from ._impl.preflight import (Preflight, PreflightError, Problem, check_rates,
                                  check_recording, mode_frequencies, preflight, resample_to)
    from ._impl.progress import EpochProgress, Eta, FractionProgress
    from ._impl.refine import (OutputErrorProblem, RefineResult, displacement_mse,
                               force_profiled_output_error, output_error, refine)
    from ._impl.pulse_kick import set_pulse_reading
    from ._impl.output_error.sample_gain import set_sample_gain_profiling
    from ._impl.report import write_report
    from ._impl.simulate import (Simulation, adjusted_stage_force, auto_substeps,
                                 set_measured_force_interp, simulate, stage_force, warmup)
    from ._impl.siva import Identification, Siva, choose_processing, recommend_best
    from ._impl.spectra import cwt, dominant_frequency, fourier_amplitude, frequency_band
    from ._impl.structure import SpecError, Structure
    from ._impl.training import SivaSettings, SivaTrainer
    from ._impl.linearized import Linearization, Settled, gauss_newton_step, linearize, settle
    from ._impl.validation import validation_score
