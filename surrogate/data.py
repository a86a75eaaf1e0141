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

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import xarray as xr

from workflows.errors import InputError

#: variables the surrogate needs, with the units the dataset must declare
UNITS = {"t": "s", "x": "m", "u": "m/s", "V": "V", "dt": "s", "Fx": "N", "Fy": "N"}
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


class DatasetError(InputError):
    """A dataset the surrogate cannot use; the message names the file and the variable."""


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
    coin_mass_kg, mu_b, gravity_m_s2 : float
        The coin's mass, ground friction coefficient and gravity (φ and g of the dynamics).
    mu_t : float
        The tip–coin friction coefficient (NaN when the file does not say).
    slip_rate_reg_m_s : float
        The FEM's friction regularisation ε_v (m/s): its tip–coin friction is
        μ_t p s/√(|s|² + ε_v²) for a slip rate s (NaN when the file does not say).
    wall_time_s : float
        The FEM run's wall time (attribute ``wall_time_total_s``; NaN when absent).
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
    coin_mass_kg: float
    mu_b: float
    gravity_m_s2: float
    wall_time_s: float
    mu_t: float = float("nan")
    slip_rate_reg_m_s: float = float("nan")

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
    """Read and check one dataset file.

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
        When the file is missing or unreadable, a variable is missing, declares other
        units than :data:`UNITS`, holds a non-finite value or does not run along ``step``,
        an attribute is missing or not a positive number, the run is not marked complete,
        or the time steps are not positive.
    """
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: no such dataset file")
    try:
        with xr.open_dataset(path, engine="h5netcdf") as ds:
            ds.load()
    except (OSError, ValueError) as err:
        raise DatasetError(f"{path}: cannot read as netCDF/HDF5 ({err})") from err
    if int(ds.attrs.get("complete", 0)) != 1:
        raise DatasetError(f"{path}: attribute 'complete' is not 1: the FEM run did not finish")
    arrays = {name: _variable(ds, path, name, units) for name, units in UNITS.items()}
    if len(arrays["t"]) < MIN_STEPS:
        raise DatasetError(f"{path}: variable 't': {len(arrays['t'])} steps, need at least {MIN_STEPS}")
    if np.any(arrays["dt"][1:] <= 0):
        bad = int(np.flatnonzero(arrays["dt"][1:] <= 0)[0]) + 1
        raise DatasetError(f"{path}: variable 'dt': non-positive time step {arrays['dt'][bad]:g} s at step {bad}")
    attrs = {name: _attribute(ds, path, name) for name in ATTRS}
    optional = {field: _attribute(ds, path, name, allow_zero=True) if name in ds.attrs else float("nan")
                for name, field in OPTIONAL_ATTRS.items()}
    return SetupData(name=path.stem, path=path, **arrays, coin_mass_kg=attrs["coin_mass_kg"],
                     mu_b=attrs["coin_mu_b"], gravity_m_s2=attrs["gravity_m_s2"],
                     wall_time_s=float(ds.attrs.get("wall_time_total_s", float("nan"))), **optional)


def _variable(ds: xr.Dataset, path: Path, name: str, units: str) -> np.ndarray:
    if name not in ds.variables:
        raise DatasetError(f"{path}: variable {name!r} is missing (need {', '.join(UNITS)})")
    var = ds[name]
    if var.dims != ("step",):
        raise DatasetError(f"{path}: variable {name!r} has dimensions {var.dims}, expected ('step',)")
    found = var.attrs.get("units")
    if found != units:
        raise DatasetError(f"{path}: variable {name!r} has units {found!r}, expected {units!r}")
    values = np.asarray(var.values, dtype=np.float64)
    if not np.all(np.isfinite(values)):
        bad = int(np.flatnonzero(~np.isfinite(values))[0])
        raise DatasetError(f"{path}: variable {name!r} has a non-finite value ({values[bad]}) at step {bad}")
    return values


def _attribute(ds: xr.Dataset, path: Path, name: str, allow_zero: bool = False) -> float:
    if name not in ds.attrs:
        raise DatasetError(f"{path}: attribute {name!r} is missing")
    try:
        value = float(ds.attrs[name])
    except (TypeError, ValueError):
        raise DatasetError(f"{path}: attribute {name!r} = {ds.attrs[name]!r} is not a number") from None
    if not np.isfinite(value) or value < 0 or (value == 0 and not allow_zero):
        allowed = "a non-negative" if allow_zero else "a positive"
        raise DatasetError(f"{path}: attribute {name!r} = {value!r} must be {allowed} number")
    return value


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
    phi : torch.Tensor
        (N, 4): the setup's coin mass (kg), μ_b, threshold voltage V^T (V; NaN where
        the dynamics does not need it) and μ_t (NaN where unknown) — the dynamics'
        parameters for that row.
    window : torch.Tensor
        (N, W, 4): the last W (s, a) pairs up to and including (s_t, a_t), padded at the
        start of each run by repeating its first pair (input of the LSTM baseline).
    v_prev : torch.Tensor
        (N,): the voltage at step t, before the increment (the DEA's state: memory of the
        tip-contact model).
    """

    s: torch.Tensor
    a: torch.Tensor
    z: torch.Tensor
    s_next: torch.Tensor
    phi: torch.Tensor
    window: torch.Tensor
    v_prev: torch.Tensor

    def __len__(self) -> int:
        return self.s.shape[0]

    def to(self, device: torch.device | str) -> "Transitions":
        return Transitions(*(getattr(self, f).to(device) for f in self.__dataclass_fields__))

    def subset(self, index: torch.Tensor) -> "Transitions":
        return Transitions(*(getattr(self, f)[index] for f in self.__dataclass_fields__))


def transitions(setups: list[SetupData], window: int, v_thresholds: dict[str, float] | None = None,
                dtype: torch.dtype = torch.float32) -> Transitions:
    """Cut runs into transitions (s_t, a_t, z_t, s_{t+1}) with their dynamics parameters.

    Parameters
    ----------
    setups : list of SetupData
    window : int
        History length of :attr:`Transitions.window` (1 for models without memory).
    v_thresholds : dict, optional
        V^T per setup name; NaN for setups not in it.
    dtype : torch.dtype
    """
    parts = []
    for data in setups:
        s, a, z = data.states(), data.actions(), data.forces()
        n = len(a)
        vt = (v_thresholds or {}).get(data.name, float("nan"))
        phi = np.tile([data.coin_mass_kg, data.mu_b, vt, data.mu_t], (n, 1))
        sa = np.concatenate([s[:-1], a], axis=1)
        padded = np.concatenate([np.repeat(sa[:1], window - 1, axis=0), sa], axis=0)
        win = np.lib.stride_tricks.sliding_window_view(padded, (window, 4))[:, 0]
        parts.append((s[:-1], a, z, s[1:], phi, win, data.V[:-1]))
    cols = [np.concatenate(c) for c in zip(*parts)]
    return Transitions(*(torch.as_tensor(c, dtype=dtype) for c in cols))
