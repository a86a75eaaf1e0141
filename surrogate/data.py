"""FEM datasets as training data: one netCDF file per setup, checked and cut into transitions.

A dataset ``<dir>/<setup>.nc`` (dimension ``step``) holds the FEM's accepted steps. The
surrogate sees it as transitions ``(s_t, a_t, z_t, s_{t+1})`` (paper, Table I):

* ``s_t = (x[t], u[t])`` — the coin's state at step t;
* ``a_t = (V[t+1], dt[t+1])`` — the action over the increment t → t+1: the voltage the FEM
  applies in that increment (the value at its end) and its length Δt;
* ``z_t = (Fx[t+1], Fy[t+1])`` — the DEA's force on the coin during that increment (the FEM
  solves the coin's backward-Euler step with the forces at the increment's end);
* ``s_{t+1} = (x[t+1], u[t+1])``.

Every check names the file and the variable, so a bad sweep fails before any training.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from deapull import dataset, provenance
from deapull import scene as scenes
from deapull.dataset import DatasetError   # re-exported: the surrogate's readers raise it
from deapull.errors import InputError
from deapull.surrogate.phi import Phi

#: variables the surrogate reads (names and units: :data:`deapull.dataset.VARIABLES`)
VARIABLES = ("t", "x", "u", "V", "dt", "Fx", "Fy")
#: global attributes the surrogate needs (positive numbers)
ATTRS = ("coin_mass_kg", "coin_mu_b", "gravity_m_s2")
#: attributes that only the tip-contact model f-coulomb needs (read when present, NaN if not):
#: the tip–coin friction coefficient μ_t (>= 0) and the FEM's friction slip-rate regularisation
OPTIONAL_ATTRS = {"coin_mu_t": "mu_t", "contact_slip_rate_reg_m_s": "slip_rate_reg_m_s"}
#: the paper's threshold: V^T is the voltage at which the coin reaches x = -1e-5 m
THRESHOLD_DISPLACEMENT_M = -1e-5
#: contact counts as lost once |Fx| + |Fy| falls below this fraction of its largest value
CONTACT_LOSS_FRACTION = 1e-3
MIN_STEPS = 10

__all__ = ["DatasetError", "SetupData", "Transitions", "load_setup", "load_sweep", "parse_setups",
           "require_tip_contact", "transitions"]


@dataclass(frozen=True)
class SetupData:
    """One setup's FEM run, as float64 arrays of length ``n_steps``.

    Attributes
    ----------
    name : str
        Setup name (``C1`` ... ``C8``), from the file name.
    path : pathlib.Path
        The file it was read from.
    t, x, u, V, dt, Fx, Fy : numpy.ndarray
        Time (s), coin displacement (m), velocity (m/s), voltage (V), time since the
        previous step (s), DEA force on the coin along x (N) and pressing force (N).
    mass_kg, mu_b, gravity_m_s2 : float
        The coin's mass, ground friction coefficient and gravity (φ and g of the dynamics).
    mu_t : float
        The tip–coin friction coefficient (NaN when the file does not say).
    slip_rate_reg_m_s : float
        The FEM's friction regularisation ε_v (m/s): its tip–coin friction is
        μ_t p s/√(|s|² + ε_v²) for a slip rate s (NaN when the file does not say).
    wall_time_s : float
        The FEM run's wall time (attribute ``wall_time_total_s``; NaN when absent).
    sha256 : str
        The file's SHA-256 (hex).
    extra : bool
        A run beside the setups' ramps (``deapull train --runs``: a push, an excitation protocol).
    scene_toml, setup : str
        The run's resolved scene and setup (its attributes; "" when absent).
    fidelity : str or None
        (property) The scene fidelity the run was made at ("" the scene file as written, a
        ``[fidelities.NAME]``, None other overrides; :func:`deapull.scene.fidelity_of_resolved`),
        worked out when first asked.
    fidelity_id : str
        (property) The fingerprint of its mesh, solver, contact and time sections ("" without
        ``scene_toml``).
    """

    name: str
    path: Path
    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    V: np.ndarray
    dt: np.ndarray
    Fx: np.ndarray
    Fy: np.ndarray
    mass_kg: float
    mu_b: float
    gravity_m_s2: float
    wall_time_s: float
    mu_t: float = float("nan")
    slip_rate_reg_m_s: float = float("nan")
    sha256: str = ""
    scene_toml: str = ""
    setup: str = ""
    extra: bool = False

    @functools.cached_property
    def _fidelity(self) -> tuple[str | None, str]:
        return scenes.fidelity_of_resolved(self.scene_toml, self.setup)

    @property
    def fidelity(self) -> str | None:
        return self._fidelity[0]

    @property
    def fidelity_id(self) -> str:
        return self._fidelity[1]

    @property
    def n_steps(self) -> int:
        return len(self.t)

    @property
    def travel_m(self) -> float:
        """The coin's largest distance from its start (m)."""
        return float(np.max(np.abs(self.x - self.x[0])))

    def threshold_voltage(self) -> float:
        """V^T: the voltage at which the coin first reaches x = -1e-5 m (linear interpolation).

        Raises
        ------
        DatasetError
            When the coin never gets that far: the paper's law has no V^T then.
        """
        reached = np.flatnonzero(self.x <= THRESHOLD_DISPLACEMENT_M)
        if reached.size == 0:
            raise DatasetError(f"{self.path}: variable 'x': the coin never reaches x = "
                               f"{THRESHOLD_DISPLACEMENT_M:g} m (min {self.x.min():.3g} m), so the "
                               "threshold voltage V^T of the paper's law is undefined")
        i = int(reached[0])
        if i == 0:
            return float(self.V[0])
        w = (THRESHOLD_DISPLACEMENT_M - self.x[i - 1]) / (self.x[i] - self.x[i - 1])
        return float(self.V[i - 1] + w * (self.V[i] - self.V[i - 1]))

    def contact_loss_voltage(self) -> float:
        """The lowest voltage from which on the DEA no longer touches the coin (inf if never).

        Contact counts as lost at the first step after which |Fx| + |Fy| stays below
        ``CONTACT_LOSS_FRACTION`` of its largest value.
        """
        force = np.abs(self.Fx) + np.abs(self.Fy)
        lost = force <= CONTACT_LOSS_FRACTION * force.max()
        if not lost[-1]:
            return float("inf")
        touching = np.flatnonzero(~lost)
        first = int(touching[-1]) + 1 if touching.size else 0
        return float(self.V[first])

    def actions(self) -> np.ndarray:
        """The FEM's actions a_t = (V[t+1], dt[t+1]), shape (n_steps - 1, 2)."""
        return np.stack([self.V[1:], self.dt[1:]], axis=1)

    def states(self) -> np.ndarray:
        """The states s_t = (x[t], u[t]), shape (n_steps, 2)."""
        return np.stack([self.x, self.u], axis=1)

    def forces(self) -> np.ndarray:
        """The forces z_t = (Fx[t+1], Fy[t+1]) of each transition, shape (n_steps - 1, 2)."""
        return np.stack([self.Fx[1:], self.Fy[1:]], axis=1)


def load_setup(path: str | Path) -> SetupData:
    """Read and check one dataset file through the dataset contract (:func:`deapull.dataset.read`).

    Parameters
    ----------
    path : str or pathlib.Path
        A ``<setup>.nc`` file written by the FEM stage (or anything in its format).

    Returns
    -------
    SetupData

    Raises
    ------
    DatasetError
        When the file is missing or unreadable, a variable of :data:`VARIABLES` is missing,
        declares other units than the contract's, holds a non-finite value or does not run
        along ``step``, an attribute of :data:`ATTRS` is missing or not a positive number
        (one of :data:`OPTIONAL_ATTRS`: present but negative), the run is not marked
        complete or has fewer than :data:`MIN_STEPS` points, or a time step is not positive.
        The message names the file and the variable or attribute.
    """
    run = dataset.read(path, VARIABLES, min_steps=MIN_STEPS)
    columns = run.columns
    dt = columns["dt"]
    if np.any(dt[1:] <= 0):
        bad = int(np.flatnonzero(dt[1:] <= 0)[0]) + 1
        raise DatasetError(f"{run.path}: variable 'dt': non-positive time step {dt[bad]:g} s at step {bad}")
    optional = {field: run.number(name, positive=False, default=float("nan"))
                for name, field in OPTIONAL_ATTRS.items()}
    return SetupData(name=run.path.stem, path=run.path, **columns, mass_kg=run.number("coin_mass_kg"),
                     mu_b=run.number("coin_mu_b"), gravity_m_s2=run.number("gravity_m_s2"),
                     wall_time_s=float(run.attrs.get("wall_time_total_s", float("nan"))), **optional,
                     sha256=provenance.file_sha256(run.path),
                     scene_toml=str(run.attrs.get("scene_toml", "")), setup=str(run.attrs.get("setup", "")))


def require_tip_contact(data: SetupData) -> None:
    """Refuse a dataset that lacks what the tip-contact model needs (μ_t, ε_v > 0)."""
    if not data.mu_t >= 0:
        raise DatasetError(f"{data.path}: attribute 'coin_mu_t' is missing: the f-coulomb model needs the "
                           "tip-coin friction coefficient")
    if not data.slip_rate_reg_m_s > 0:
        raise DatasetError(f"{data.path}: attribute 'contact_slip_rate_reg_m_s' is missing or 0: the f-coulomb "
                           "model needs the FEM's friction regularisation (datasets written before it was "
                           "recorded: rerun the sweep)")


def parse_setups(text: str) -> list[str]:
    """``"C1,C2"`` → ``["C1", "C2"]``; refuses an empty list."""
    names = [s.strip() for s in text.split(",") if s.strip()]
    if not names:
        raise InputError(f"no setup named in {text!r} (expected e.g. C1 or C1,C2)")
    return names


def load_sweep(data_dir: str | Path, setups: list[str]) -> dict[str, SetupData]:
    """Load ``<data_dir>/<setup>.nc`` for each setup, in order."""
    data_dir = Path(data_dir)
    if not data_dir.is_dir():
        raise DatasetError(f"{data_dir}: no such data folder")
    return {name: load_setup(data_dir / f"{name}.nc") for name in setups}


@dataclass(frozen=True)
class Transitions:
    """Transitions of one or more setups as float tensors, one row per transition.

    Attributes
    ----------
    s, a, z, s_next : torch.Tensor
        (N, 2) each: state (x, u), action (V, Δt), forces (Fx, Fy), next state.
    phi : Phi
        φ of each row's setup, fields of shape (N,): coin mass (kg), μ_b, μ_t and the
        threshold voltage V^T (V) — NaN where unknown or not needed.
    window : torch.Tensor
        (N, W, 4): the last W (s, a) pairs up to and including (s_t, a_t), padded at the
        start of each run by repeating its first pair (input of the LSTM baseline).
    v_prev : torch.Tensor
        (N,): the voltage at step t, before the increment (the DEA's state: memory of the
        tip-contact model).
    z_prev : torch.Tensor
        (N, 2): the forces (Fx, Fy) at step t, before the increment (0 at a run's first point:
        the FEM places the DEA without friction); with ``v_prev`` the memory of the
        tip-memory model (``f-memory``), whose tip carries the friction force Fx between steps.
    """

    s: torch.Tensor
    a: torch.Tensor
    z: torch.Tensor
    s_next: torch.Tensor
    phi: Phi
    window: torch.Tensor
    v_prev: torch.Tensor
    z_prev: torch.Tensor

    def __len__(self) -> int:
        return self.s.shape[0]

    def to(self, device: torch.device | str) -> "Transitions":
        return Transitions(*(getattr(self, f).to(device) for f in self.__dataclass_fields__))

    def subset(self, index: torch.Tensor) -> "Transitions":
        return Transitions(*(getattr(self, f)[index] for f in self.__dataclass_fields__))


def transitions(setups: list[SetupData], window: int, phis: dict[str, Phi] | None = None,
                dtype: torch.dtype = torch.float32) -> Transitions:
    """Cut runs into transitions (s_t, a_t, z_t, s_{t+1}) with their coin's φ.

    Parameters
    ----------
    setups : list of SetupData
    window : int
        History length of :attr:`Transitions.window` (1 for models without memory).
    phis : dict, optional
        φ per setup name (e.g. ``kind_class.phi_of(data)``); a setup not in it gets
        :meth:`Phi.of` (no V^T).
    dtype : torch.dtype
    """
    parts, row_phis = [], []
    for data in setups:
        s, a, z = data.states(), data.actions(), data.forces()
        phi = (phis or {}).get(data.name)
        row_phis.append(Phi.of(data) if phi is None else phi)
        sa = np.concatenate([s[:-1], a], axis=1)
        padded = np.concatenate([np.repeat(sa[:1], window - 1, axis=0), sa], axis=0)
        win = np.lib.stride_tricks.sliding_window_view(padded, (window, 4))[:, 0]
        z_prev = np.stack([data.Fx[:-1], data.Fy[:-1]], axis=1)
        parts.append((s[:-1], a, z, s[1:], win, data.V[:-1], z_prev))
    s, a, z, s_next, win, v_prev, z_prev = (torch.as_tensor(np.concatenate(c), dtype=dtype) for c in zip(*parts))
    phi = Phi.rows(row_phis, [len(p[1]) for p in parts], dtype=dtype)
    return Transitions(s, a, z, s_next, phi, win, v_prev, z_prev)
