"""A band on every rollout from the ensemble of a model's restarts.

Training with ``restarts`` ≥ 2 fits the same model from several seeds
(:func:`surrogate.train.train`); their rollouts x_k(t) disagree most where the data pin the
model least. The band of a rollout is

    x̄(t) ± k (σ(t) + δ),   x̄, σ: mean and standard deviation over the members,

with a floor δ = :data:`FLOOR_SHARE` × max |x̄| (members that agree exactly still leave the
FEM's own spread) and k calibrated on the validation run(s): the :data:`LEVEL` quantile of
|x_FEM − x̄| / (σ + δ) over their points, so that the band covers that share of the
validation points. Its coverage of held-out runs (the test setups of ``deapull
experiments``) is what the band is judged by.

The models train where the voltage rises; once it has fallen (a release, a triangle's turn)
they extrapolate, and their error grows well beyond the members' spread. So a band may carry
a second scale k_fallen for the points at and after the voltage's first fall
(:func:`fallen`), calibrated on the validation runs' points there (``deapull
experiments-protocols``: the validation coin's excitation runs), k for the points before. :func:`save` writes the members under
``<model>/members/seed<k>/`` and the calibration into ``ensemble.json``.
"""
from __future__ import annotations

import json
import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from deapull.errors import InputError
from deapull.io import write_text
from deapull.surrogate import store
from deapull.surrogate.rollout import OutOfRangeWarning, rollout

#: the share of points a band is calibrated to cover
LEVEL = 0.9
#: the band's floor, as a share of the largest |x̄| of the rollout
FLOOR_SHARE = 2e-3
MEMBERS, CALIBRATION = "members", "ensemble.json"


@dataclass
class Band:
    """A rollout's band: ``t`` (s), ``mean``, ``lower``, ``upper`` and the members' ``x`` (M, T + 1), in m."""

    t: np.ndarray
    mean: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    x: np.ndarray

    def coverage(self, x_true: np.ndarray) -> float:
        """The share of the predicted points (after the first) inside the band."""
        inside = (x_true[1:] >= self.lower[1:]) & (x_true[1:] <= self.upper[1:])
        return float(inside.mean())

    def half_width_share(self, x_true: np.ndarray) -> float:
        """The band's mean half-width over the predicted points, as a share of the run's travel
        (the largest |x| of ``x_true``): how much a coverage costs."""
        return float(0.5 * (self.upper[1:] - self.lower[1:]).mean() / np.abs(x_true).max())


def member_x(models, data, phi) -> np.ndarray:
    """(M, T + 1): each member's 1 s rollout of ``data``'s actions for the coin ``phi``."""
    out = []
    with torch.inference_mode(), warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        for model in models:
            out.append(rollout(model, phi, data.states()[0], data.actions()).states[0, :, 0].double().numpy())
    return np.stack(out)


def _spread(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    mean = x.mean(0)
    return mean, x.std(0) + FLOOR_SHARE * np.abs(mean).max()


def fallen(data) -> np.ndarray:
    """(T + 1,) bool: the points at and after the first where the voltage is below an earlier one."""
    V = np.asarray(data.V, dtype=float)
    drop = V < np.maximum.accumulate(V) - 1e-9 * max(np.abs(V).max(), 1.0)
    return np.logical_or.accumulate(drop)


def calibrate(models, val_sets, phis: dict, level: float = LEVEL, where=None) -> float:
    """k such that x̄ ± k (σ + δ) covers ``level`` of the validation runs' points (of those
    where ``where(data)`` is True, when given; NaN where there are none)."""
    if len(models) < 2:
        raise InputError(f"an ensemble needs at least 2 members, got {len(models)} (train with restarts >= 2)")
    ratios = []
    for data in val_sets:
        mean, width = _spread(member_x(models, data, phis[data.name]))
        keep = np.ones(len(data.x), dtype=bool) if where is None else where(data)
        ratios.append((np.abs(data.x - mean) / width)[1:][keep[1:]])
    ratios = np.concatenate(ratios)
    return float(np.quantile(ratios, level)) if len(ratios) else math.nan


def band(models, k: float, data, phi, k_fallen: float | None = None) -> Band:
    """The band of the rollout of ``data``'s actions for the coin ``phi``; with ``k_fallen``,
    that scale where the voltage has fallen (:func:`fallen`)."""
    x = member_x(models, data, phi)
    mean, width = _spread(x)
    if k_fallen is not None:
        width = width * np.where(fallen(data), k_fallen / k, 1.0)
    return Band(t=data.t, mean=mean, lower=mean - k * width, upper=mean + k * width, x=x)


def save(result, folder: str | Path, k: float, k_fallen: float | None = None,
         calibrated_on: list[str] | None = None) -> Path:
    """Write the members of a :class:`~deapull.surrogate.train.TrainResult` and the calibration: ``k``
    (and ``k_fallen``), calibrated on the runs named ``calibrated_on`` (default: the validation runs)."""
    folder = Path(folder)
    seeds = [r["seed"] for r in result.restarts]
    for seed, model in zip(seeds, result.members):
        store.save(model, folder / MEMBERS / f"seed{seed}")
    runs = [d.name for d in result.val_sets] if calibrated_on is None else list(calibrated_on)
    write_calibration(folder, k, runs, k_fallen, seeds)
    return folder


def calibration(folder: str | Path) -> dict:
    """A saved ensemble's ``ensemble.json``: k, k_fallen (None: k throughout), the seeds and the
    runs it was calibrated on."""
    return json.loads((Path(folder) / CALIBRATION).read_text())


def write_calibration(folder: str | Path, k: float, runs: list[str], k_fallen: float | None = None,
                      seeds: list[int] | None = None) -> None:
    """Write a saved ensemble's k (and k_fallen), calibrated on the runs named ``runs`` (its seeds:
    ``seeds``, default those already written)."""
    path = Path(folder) / CALIBRATION
    seeds = calibration(folder)["seeds"] if seeds is None else seeds
    write_text(path, json.dumps({"level": LEVEL, "floor_share": FLOOR_SHARE, "k": k, "k_fallen": k_fallen,
                                 "seeds": seeds, "calibrated_on": runs}, indent=2) + "\n")


def load(folder: str | Path) -> tuple[list, float]:
    """The members of a saved ensemble (seed order) and its k."""
    folder = Path(folder)
    path = folder / CALIBRATION
    if not path.is_file():
        raise InputError(f"{path}: missing; the model in {folder} was saved without its ensemble (train with "
                         "restarts >= 2 in `deapull experiments`)")
    meta = json.loads(path.read_text())
    return [store.load(folder / MEMBERS / f"seed{s}")[0] for s in meta["seeds"]], float(meta["k"])
