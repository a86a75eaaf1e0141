"""Error of a 1 s rollout against the FEM on a test setup (paper §VI-A, Table II).

The model is rolled out recursively from the FEM's initial state under the FEM's actions;
physics models simulate the test coin, φ = ``model.phi_of(data)`` (its m_c and μ_b; for
the paper's law its V^T from the test run, as the paper does; for the tip-contact model
its μ_t). Errors are over the rollout's T predicted steps.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from deapull.surrogate.data import SetupData
from deapull.surrogate.models import Surrogate
from deapull.surrogate.phi import Phi
from deapull.surrogate.rollout import rollout

#: a rollout that leaves the FEM's travel by this factor (or turns non-finite) has diverged
DIVERGED_FACTOR = 10.0
#: metric key → (label, unit, scale used in tables)
METRICS = {
    "mae_x_m": ("MAE x", "1e-4 m", 1e-4),
    "mae_u_m_s": ("MAE u", "1e-4 m/s", 1e-4),
    "mae_Fx_N": ("MAE Fx", "1e-4 N", 1e-4),
    "mae_Fy_N": ("MAE Fy", "1e-4 N", 1e-4),
    "x_error_pct_travel": ("x error", "% of travel", 1.0),
    "max_abs_x_error_m": ("max |x error|", "1e-4 m", 1e-4),
    "rollout_ms": ("rollout", "ms", 1.0),
}


@dataclass
class Evaluation:
    """A model's rollout on one setup, against the FEM.

    Attributes
    ----------
    metrics : dict
        The keys of :data:`METRICS` (force errors None for the black boxes) plus
        ``setup``, ``kind``, ``steps``, ``travel_m``, ``final_x_error_m``, ``engine`` and
        ``diverged`` (the rollout went non-finite or beyond ``DIVERGED_FACTOR`` × the travel).
    t : numpy.ndarray
        (T + 1,) time (s).
    x_fem, x_model : numpy.ndarray
        (T + 1,) coin displacement of the FEM and of the rollout (m).
    """

    metrics: dict
    t: np.ndarray
    x_fem: np.ndarray
    x_model: np.ndarray

    @property
    def abs_x_error(self) -> np.ndarray:
        """|x_model - x_fem| over the predicted steps (m)."""
        return np.abs(self.x_model[1:] - self.x_fem[1:])


def evaluate(model: Surrogate, data: SetupData, engine: str = "auto", strict: bool = False,
             phi: Phi | None = None) -> Evaluation:
    """Roll ``model`` out on ``data``'s actions and compare with the FEM.

    Parameters
    ----------
    model : Surrogate
    data : SetupData
        The test setup.
    phi : Phi, optional
        The coin to simulate; default ``model.phi_of(data)``, the test coin.
    engine : {"auto", "torch", "native"}
    strict : bool
        Raise when an input leaves the training range (else warn).

    Returns
    -------
    Evaluation
    """
    if phi is None:
        phi = model.phi_of(data)
    with torch.inference_mode():
        result = rollout(model, phi, data.states()[0], data.actions(), engine=engine, strict=strict,
                         label=f"{model.kind} on {data.name}")
    states = result.states[0].double().cpu().numpy()
    x_err = np.abs(states[1:, 0] - data.x[1:])
    travel = data.travel_m
    metrics = {"setup": data.name, "kind": model.kind, "steps": data.n_steps - 1, "travel_m": travel,
               "mae_x_m": float(x_err.mean()), "mae_u_m_s": float(np.abs(states[1:, 1] - data.u[1:]).mean()),
               "mae_Fx_N": None, "mae_Fy_N": None,
               "x_error_pct_travel": float(100 * x_err.mean() / travel) if travel > 0 else float("nan"),
               "max_abs_x_error_m": float(x_err.max()), "final_x_error_m": float(states[-1, 0] - data.x[-1]),
               "rollout_ms": 1e3 * result.wall_time_s, "engine": result.engine,
               "diverged": bool(not np.all(np.isfinite(states)) or np.abs(states[:, 0]).max() > DIVERGED_FACTOR * travel)}
    if result.forces is not None:
        forces = result.forces[0].double().cpu().numpy()
        metrics["mae_Fx_N"] = float(np.abs(forces[:, 0] - data.Fx[1:]).mean())
        metrics["mae_Fy_N"] = float(np.abs(forces[:, 1] - data.Fy[1:]).mean())
    return Evaluation(metrics=metrics, t=data.t, x_fem=data.x, x_model=states[:, 0])


def format_table(rows: list[dict]) -> str:
    """A plain-text table of evaluation metrics, one row per evaluation."""
    head = ["setup", "model"] + [f"{label} [{unit}]" for label, unit, _ in METRICS.values()]
    lines = [head]
    for r in rows:
        cells = [r["setup"], r["kind"]]
        for key, (_, _, scale) in METRICS.items():
            cells.append("-" if r.get(key) is None else f"{r[key] / scale:.3g}")
        lines.append(cells)
    widths = [max(len(line[i]) for line in lines) for i in range(len(head))]
    return "\n".join("  ".join(c.rjust(w) for c, w in zip(line, widths)) for line in lines)
