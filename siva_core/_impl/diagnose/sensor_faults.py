"""Sensor faults: what a faulty sensor does to a record, and how to undo it.

A leaf module (records in, records out): the candidate results and the sensor scans both
use it, so neither has to import the other.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable, Sequence

import numpy as np

from ..recording import Recording

if TYPE_CHECKING:
    from ..processing import Processing
    from ..structure import Structure

#: gain errors scanned (measured / true); a sensitivity off by more than 2x is a wiring fault
GAINS = tuple(float(x) for x in np.exp(np.linspace(np.log(0.7), np.log(1.4), 7)))
#: channel delays scanned, in samples of the record (both signs)
DELAY_SAMPLES = (-4.0, -2.0, -1.0, 1.0, 2.0, 4.0)


@dataclass(frozen=True)
class SensorFault:
    """One sensor fault on one channel (quacks like an ``Effect`` for the ranking)."""

    name: str
    kind: str
    explanation: str
    magnitude: str
    unit: str
    family: str = "sensor"
    positive: frozenset[str] = frozenset()

    @property
    def is_gain(self) -> bool:
        return self.magnitude == "gain"

    @property
    def fault_free(self) -> float:
        """The value of a sensor without this fault (gain 1, delay 0)."""
        return 1.0 if self.is_gain else 0.0

    def describe(self, coeffs: dict[str, float]) -> str:
        v = coeffs.get(self.magnitude)
        if v is None:
            return self.explanation
        if self.is_gain:
            return f"{self.explanation} Identified gain {v:.4g} ({100 * (v - 1):+.1f} %)."
        return f"{self.explanation} Identified delay {1e3 * v:.4g} ms."

    def grid(self, fs: float) -> list[float]:
        return list(GAINS) if self.is_gain else [s / fs for s in DELAY_SAMPLES]


ACC_GAIN = SensorFault(
    "accelerometer_gain", "accelerometer_gain",
    "an accelerometer's sensitivity is off: its channel is scaled by a constant factor on "
    "every record, which no structural parameter reproduces at every mode alike "
    "(with known masses).", "gain", "-")
CHANNEL_DELAY = SensorFault(
    "channel_delay", "channel_delay",
    "one channel lags the others by a constant time (a filter or buffer offset on that "
    "input): a phase error growing in proportion to frequency, on every record alike.",
    "delay", "s")
FORCE_GAIN = SensorFault(
    "force_gain", "force_gain",
    "the force transducer's sensitivity is off: every response is scaled against the "
    "measured force by the same factor, which no stiffness or damping can mimic when the "
    "masses are known.", "gain", "-")

SENSOR_FAULTS = {f.name: f for f in (ACC_GAIN, CHANNEL_DELAY, FORCE_GAIN)}


def response_channel(channels: "Sequence[str] | dict", dof: str) -> str | None:
    """The response channel of ``dof`` a sensor fault sits on: the first measured of
    acceleration, velocity, displacement (one per DOF: the others are derived from it)."""
    return next((f"{q}_{dof}" for q in ("acc", "vel", "disp") if f"{q}_{dof}" in channels),
                None)


def corrected(records: Sequence[Recording], fault: SensorFault, channel: str,
              value: float) -> list[Recording]:
    """The records as a sensor without the fault would have given them."""
    out = []
    for r in records:
        if channel not in r.channels:
            out.append(r)
            continue
        x = np.asarray(r.channels[channel], float)
        if fault.is_gain:
            y = x / value
        else:  # measured(t) = true(t - delay)  ->  true(t) = measured(t + delay)
            y = np.interp(r.time + value, r.time, x)
        out.append(dataclasses.replace(r, channels={**r.channels, channel: y}))
    return out


def corrected_cost(structure: "Structure", theta: np.ndarray, train: Sequence[Recording],
                   fault: SensorFault, channel: str, value: float, proc: "Processing") -> float:
    """Output-error train cost of ``theta`` on ``train`` corrected for ``fault`` at
    ``value``; inf where the chain cannot process the corrected records (a value a scan
    steps over, not an error)."""
    from ..refine import output_error

    try:
        x = float(output_error(structure, theta[None], corrected(train, fault, channel, value),
                               proc)[0])
    except Exception:  # noqa: BLE001 - a value the chain cannot process
        return math.inf
    return x if np.isfinite(x) else math.inf


@dataclass
class ValueParabola:
    """A parabola through the train costs at a fault's value and one step either side
    (a gain in log steps, a delay in seconds): where its vertex lies, and how sharply the
    cost rises around it (the curvature ``a`` gives the value a rough interval)."""

    v: float
    is_gain: bool
    costs: np.ndarray
    a: float
    x_best: float

    def value(self, x: float | None = None) -> float:
        x = self.x_best if x is None else x
        return self.v * math.exp(x) if self.is_gain else self.v + x

    def interval(self, cost: float, n: int) -> tuple[float, float] | None:
        """A rough 95 % interval of the value from the curvature and the residual
        variance ``cost`` over ``n`` samples; None when the costs do not curve upward."""
        if not self.a > 0:
            return None
        sd = math.sqrt(max(2 * cost / max(n, 1) / (2 * self.a), 0.0))
        lo, hi = self.value(self.x_best - 1.96 * sd), self.value(self.x_best + 1.96 * sd)
        return min(lo, hi), max(lo, hi)


def value_parabola(cost_at: Callable[[float], float], v: float, is_gain: bool, step: float,
                   reach: float) -> ValueParabola:
    """``cost_at(value)`` at ``v`` and one ``step`` either side; the vertex within
    ``reach`` steps, or the lowest of the three when they do not curve upward."""
    par = ValueParabola(v, is_gain, np.empty(3), 0.0, 0.0)
    xs = np.array([-step, 0.0, step])
    par.costs = np.array([cost_at(par.value(x)) for x in xs])
    a, b, _ = np.polyfit(xs, par.costs, 2) if np.all(np.isfinite(par.costs)) else (0.0, 0.0, 0.0)
    par.a = float(a)
    par.x_best = float(np.clip(-b / (2 * a), -reach * step, reach * step)) if a > 0 else \
        float(xs[int(np.argmin(par.costs))])
    return par

