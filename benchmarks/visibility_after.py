"""The visibility of a scenario's effect *after the nominal refit* (issue 16, branch
absorbed): what the refitted linear model cannot absorb, i.e. what is identifiable.

``scenarios.draw`` measures each effect's visibility *before* any fit: the RMS change the
effect makes on the clean validation accelerations over the RMS of the white noise.  But
the diagnosis first refits every nominal parameter to the train records, and that refit
absorbs part of a missing element (a missing spring m1-m3 is largely a retuned set of
the model's own springs; a clearance seen at one train amplitude is a stiffer linear
spring there).  ``after(sc)`` measures, per structural effect and with the same
normalisation as ``visibility``:

1. the clean train and validation responses of the true structure with that effect alone
   (the generator's straight-line force reading, as its visibility),
2. the nominal model's free parameters fitted to the clean train responses by output
   error (least squares on the accelerations over the noise scale, started at the truth:
   the best the nominal model can do, without noise),
3. the RMS of what that refitted model leaves on the clean validation responses over the
   RMS of the white noise, the largest over the validation records.

A sensor fault has no visibility here either (as in ``sc.visibility``).
"""
from __future__ import annotations

from typing import Any

import numpy as np
from scipy.optimize import least_squares

import scenarios
from siva_core import Structure, simulate, with_effect

MAX_NFEV = 60  # least-squares evaluations (x the parameters' Jacobian columns) at most


def _clean(st: Structure, theta: np.ndarray, sc: scenarios.Scenario, peak: float
           ) -> np.ndarray:
    t = np.asarray(sc.train[0].time, float)
    kf = sc.nominal.dofs.index(sc.force_dof)
    F = np.zeros((len(t), st.n_dof))
    F[:, kf] = scenarios._pulse(t, peak, sc.info["pulse_s"])
    z = np.zeros(st.n_dof)
    return np.asarray(simulate(st, theta, t, z, z, F, substeps="auto").a)


def after_one(sc: scenarios.Scenario, kind: str, place: tuple[str, str],
              coeffs: dict[str, float]) -> dict[str, Any]:
    """Visibility before and after the nominal refit of one effect on ``sc``'s records."""
    nom = sc.nominal
    theta0 = np.asarray(nom.vector(sc.truth), float)
    gen = with_effect(nom, kind, place, coeffs)
    peaks = {"train": sc.info["train_peaks"], "val": sc.info["val_peaks"]}
    noise = sc.info["noise"]
    base = {p: _clean(nom, theta0, sc, p) for ps in peaks.values() for p in ps}
    target = {p: _clean(gen, np.asarray(gen.vector(sc.truth), float), sc, p)
              for ps in peaks.values() for p in ps}
    sigma = {p: noise * np.max(np.abs(base[p]), axis=0) for p in base}
    free = theta0 != 0

    def theta_of(x: np.ndarray) -> np.ndarray:
        th = theta0.copy()
        th[free] = theta0[free] * np.exp(x)
        return th

    def res(x: np.ndarray) -> np.ndarray:
        th = theta_of(x)
        out = [((_clean(nom, th, sc, p) - target[p]) / sigma[p]).ravel()
               for p in peaks["train"]]
        r = np.concatenate(out)
        return np.where(np.isfinite(r), r, 1e6)

    fit = least_squares(res, np.zeros(int(free.sum())), method="trf", x_scale=0.1,
                        max_nfev=MAX_NFEV)
    th = theta_of(fit.x)

    def vis(p: float, model: np.ndarray) -> float:
        d = target[p] - model
        return float(np.sqrt(np.mean(d ** 2)) / np.sqrt(np.mean(sigma[p] ** 2)))

    return {"before": max(vis(p, base[p]) for p in peaks["val"]),
            "after": max(vis(p, _clean(nom, th, sc, p)) for p in peaks["val"]),
            "train_after": max(vis(p, _clean(nom, th, sc, p)) for p in peaks["train"]),
            "refit": {n: float(a / b) for n, a, b in zip(nom.free, th, theta0)
                      if b != 0 and abs(a / b - 1) > 1e-3}}


def after(sc: scenarios.Scenario) -> tuple[list[float], list[float]]:
    """Each structural effect's visibility after the nominal refit on the validation
    records and on the train records themselves, in the order of ``sc.visibility`` (a
    sensor fault has none, as there).  An effect visible on the validation records
    but not on the train ones after the refit shows only by extrapolation: the train
    records cannot tell it from a retuned linear model (fresh seed 17227: 4.3 and 1.0 x)."""
    val: list[float] = []
    train: list[float] = []
    for kind, place, coeffs in sc.effects:
        try:
            out = after_one(sc, kind, place, coeffs)
            val.append(out["after"])
            train.append(out["train_after"])
        except Exception:  # noqa: BLE001 - unmeasured, as the visibility of a failed draw
            val.append(float("nan"))
            train.append(float("nan"))
    return val, train
