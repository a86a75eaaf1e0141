"""A band on every rollout from the ensemble of a model's restarts.

Training with ``restarts`` ≥ 2 fits the same model from several seeds
(:func:`surrogate.train.train`); their rollouts x_k(t) disagree most where the data pin the
model least. The band of a rollout is

    x̄(t) ± k (σ(t) + δ),   x̄, σ: mean and standard deviation over the members,

with a floor δ = :data:`FLOOR_SHARE` × max |x̄| (members that agree exactly still leave the
FEM's own spread) and k calibrated on the validation run(s): the :data:`LEVEL` quantile of
|x_FEM − x̄| / (σ + δ) over their points, so that the band covers that share of the
validation points. Its coverage of held-out runs (the test setups of ``deapull
experiments``) is what the band is judged by. :func:`save` writes the members under
``<model>/members/seed<k>/`` and the calibration into ``ensemble.json``.
"""
from __future__ import annotations

import json
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


def calibrate(models, val_sets, phis: dict, level: float = LEVEL) -> float:
    """k such that x̄ ± k (σ + δ) covers ``level`` of the validation runs' points."""
    if len(models) < 2:
        raise InputError(f"an ensemble needs at least 2 members, got {len(models)} (train with restarts >= 2)")
    ratios = []
    for data in val_sets:
        mean, width = _spread(member_x(models, data, phis[data.name]))
        ratios.append(np.abs(data.x[1:] - mean[1:]) / width[1:])
    return float(np.quantile(np.concatenate(ratios), level))


def band(models, k: float, data, phi) -> Band:
    """The band of the rollout of ``data``'s actions for the coin ``phi``."""
    x = member_x(models, data, phi)
    mean, width = _spread(x)
    return Band(t=data.t, mean=mean, lower=mean - k * width, upper=mean + k * width, x=x)


def save(result, folder: str | Path, k: float) -> Path:
    """Write the members of a :class:`~deapull.surrogate.train.TrainResult` and the calibration ``k``."""
    folder = Path(folder)
    seeds = [r["seed"] for r in result.restarts]
    for seed, model in zip(seeds, result.members):
        store.save(model, folder / MEMBERS / f"seed{seed}")
    write_text(folder / CALIBRATION, json.dumps({"level": LEVEL, "floor_share": FLOOR_SHARE, "k": k,
                                                 "seeds": seeds, "calibrated_on": [d.name for d in result.val_sets]},
                                                indent=2) + "\n")
    return folder


def load(folder: str | Path) -> tuple[list, float]:
    """The members of a saved ensemble (seed order) and its k."""
    folder = Path(folder)
    path = folder / CALIBRATION
    if not path.is_file():
        raise InputError(f"{path}: missing; the model in {folder} was saved without its ensemble (train with "
                         "restarts >= 2 in `deapull experiments`)")
    meta = json.loads(path.read_text())
    return [store.load(folder / MEMBERS / f"seed{s}")[0] for s in meta["seeds"]], float(meta["k"])
