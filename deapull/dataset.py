"""The dataset contract between the FEM and every reader: variables, units, attributes.

One FEM run is one file (netCDF4/HDF5 through xarray's h5netcdf engine), dimension
``step``, one point per accepted time step. The writer (:mod:`deapull.fem_solver.run`)
builds it with :func:`build` and :func:`write`; the readers (the surrogate's
:func:`deapull.surrogate.data.load_setup`, the studies, the plots) open it with
:func:`read`, which checks what they ask for and names the file and the variable in every
error. Nothing here needs dolfinx or torch.

Variables follow the paper's Table I (``t x u V dt Fx Fy``) plus solver diagnostics, each
with ``units`` and ``long_name`` (CF style). Attributes carry the resolved scene, the
coin's parameters, mesh statistics, package versions, the git commit and wall time. A file
is written to a temporary name and renamed, and says ``complete = 1``.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from deapull.errors import InputError
from deapull.io import atomic_write

ENGINE = "h5netcdf"
DIM = "step"

#: the coin speeds, as shares of the patch's speed, at which the FEM probes the patch's friction
PATCH_SHARES = (0.0, 0.5, 0.75, 0.9, 0.95, 1.0)
#: their variables (patch_drag_050: the coin at 0.5 x patch_vx)
PATCH_DRAGS = tuple(f"patch_drag_{round(100 * s):03d}" for s in PATCH_SHARES)

#: every variable of a dataset: name -> (units, long_name)
VARIABLES = {
    "t": ("s", "time"),
    "x": ("m", "coin displacement along x (motion toward -x)"),
    "u": ("m/s", "coin velocity along x"),
    "V": ("V", "voltage across each dielectric film"),
    "dt": ("s", "time since the previous data point (0 at the first)"),
    "Fx": ("N", "force of the DEA on the coin along x"),
    "Fy": ("N", "pressing force of the DEA on the coin, positive downward"),
    "newton_iterations": ("1", "Newton iterations of the step (all coupling iterations)"),
    "coupling_iterations": ("1", "DEA-coin coupling iterations of the step"),
    "cutbacks": ("1", "step cut-backs before the step was accepted"),
    "penetration_m": ("m", "largest penetration of the DEA's underside nodes into the obstacle"),
    "penetration_qp_m": ("m", "largest penetration into the obstacle at the contact integral's quadrature "
                              "points (where the penalty acts)"),
    "stick": ("1", "1 when the coin sticks on the ground"),
    "force_balance_residual_N": ("N", "coin momentum balance with the DEA force taken from the clamp reaction "
                                      "(independent of the contact integral the coupling used)"),
    "tip_ux": ("m", "mean x displacement of the DEA's free-end face"),
    "tip_uy": ("m", "mean y displacement of the DEA's free-end face"),
    "tip_uz": ("m", "mean z displacement of the DEA's free-end face"),
    "mean_abs_J_minus_1": ("1", "volume average of |J - 1| (incompressibility check)"),
    "volume_change": ("1", "relative change of the DEA's volume, (integral of J - V0) / V0"),
    "n_contact": ("1", "quadrature points of the DEA-obstacle contact integral that touch the obstacle "
                       "(penetration > 0), in the modelled mesh (a half model: its half)"),
    "contact_x": ("m", "x of the DEA-obstacle contact centre: current positions weighted by the normal "
                       "traction (0 when nothing touches)"),
    "contact_z": ("m", "z of the contact centre (0 for a half model, whose mirror image balances it)"),
    "contact_abs_z": ("m", "traction-weighted mean |z| of the DEA-obstacle contact: how far from the mid-plane "
                           "z = 0 the patch sits, the same for a half and a whole model (0 when nothing touches)"),
    "table_Rx": ("N", "force of the table on the DEA along x (0 without a [table]); never part of Fx"),
    "table_Ry": ("N", "force of the table on the DEA along y, upward (0 without a [table]); never part of Fy"),
    "table_penetration_m": ("m", "largest penetration of the DEA's underside into the table at the table "
                                 "integral's quadrature points"),
    "patch_vx": ("m/s", "x velocity of the DEA's points that touch the obstacle, weighted by the normal traction "
                        "(0 when nothing touches): the patch's speed"),
    "patch_normal_x": ("N", "x force of the normal traction alone on the obstacle (the rim's fillet pushes it "
                            "back toward +x); part of Fx"),
    **{name: ("N", f"x force the DEA-obstacle friction would put on the obstacle per unit mu_t, were the obstacle "
                   f"moving at {share:g} x patch_vx (the patch's friction-speed curve: a DEA-side probe "
                   f"of the solved step, the same integrand and points as Fx)")
       for share, name in zip(PATCH_SHARES, PATCH_DRAGS)},
    "wall_time_s": ("s", "wall time of the step"),
}
#: the variables of the paper's Table I: every dataset has them
REQUIRED = ("t", "x", "u", "V", "dt", "Fx", "Fy")

#: global attributes a reader may rely on: name -> meaning (units in the name)
ATTRIBUTES = {
    "complete": "1 when the run finished and the file was written whole",
    "scene": "scene name", "setup": "setup name (empty when the scene has none)",
    "scene_toml": "the resolved scene, as TOML",
    "coin_mass_kg": "coin mass: mesh volume x density",
    "coin_mu_t": "Coulomb friction DEA-coin", "coin_mu_b": "Coulomb friction coin-ground",
    "coin_density_kg_m3": "coin density",
    "contact_slip_rate_reg_m_s": "slip-rate regularisation eps_v of the DEA-coin friction",
    "contact_slip_rate_reg_bias": "what eps_v does to the coin travel, as measured (docs/fem_accuracy.md)",
    "contact_quadrature": "points of the contact integrals: rule and degree",
    "contact_penalty_N_m3": "normal penalty k_n of the DEA-obstacle contact (N/m^3)",
    "contact_min_active_points": "fewest contact points a step should have (contact.min_active_points)",
    "contact_steps_below_min_points": "steps whose DEA-obstacle contact had fewer active points than that "
                                      "(the patch is not resolved there; n_contact per step)",
    "table": "the DEA-table contact part: height, mu_g, penalty, rule; 'none' without one",
    "mesh_symmetry": "'half_z' (the half z >= 0, forces doubled) or 'none'",
    "mesh_divisions": "element divisions of the full width (x, z, active, passive)",
    "gravity_m_s2": "gravitational acceleration", "voltage_max_V": "largest voltage of the protocol",
    "wall_time_total_s": "wall time of the whole run", "coin_travel_m": "the coin's largest |x| (it starts at x = 0)",
    "coin_motion": "which way the coin went: 'toward -x (away from the clamp)' (coin_pull), "
                   "'toward +x (toward the clamp)' (coin_release) or 'none'",
    "load_protocol": "the voltage protocol (deapull/protocol.py)",
    "steps": "number of points", "git_commit": "commit of the code that wrote the file",
}


class DatasetError(InputError):
    """A dataset that does not meet the contract; the message names the file and the variable."""


def build(columns: Mapping[str, Sequence[float]], attrs: Mapping[str, object]):
    """The xarray Dataset of one run from its step columns; refuses a missing, extra or
    non-finite variable. ``complete = 1`` is set."""
    import xarray as xr  # lazy: xarray loads pandas; `import deapull` and readers of the contract alone skip it
    missing = [n for n in VARIABLES if n not in columns]
    extra = [n for n in columns if n not in VARIABLES]
    if missing or extra:
        raise ValueError(f"dataset columns do not match the contract: missing {missing}, unknown {extra}")
    data = {}
    for name, (units, long_name) in VARIABLES.items():
        values = np.asarray(columns[name], dtype=float)
        if not np.all(np.isfinite(values)):
            raise ValueError(f"variable {name!r} has non-finite values; refusing to write a dataset")
        data[name] = (DIM, values, {"units": units, "long_name": long_name})
    n = len(data["t"][1])
    ds = xr.Dataset(data, coords={DIM: np.arange(n)})
    ds.attrs.update({k: _attr(v) for k, v in attrs.items()})
    ds.attrs["complete"] = 1
    return ds


def _attr(value):
    if isinstance(value, bool):
        return int(value)
    if value is None:
        return ""
    return value


def write(ds, path: str | os.PathLike) -> Path:
    """Write ``ds`` to ``path`` atomically (temporary file + rename)."""
    return atomic_write(path, lambda tmp: ds.to_netcdf(tmp, engine=ENGINE))


def is_complete(path: str | os.PathLike, scene_toml: str | None = None) -> bool:
    """True when ``path`` is a readable dataset marked complete with the required variables
    (and, given ``scene_toml``, made with that resolved scene: its ``scene_toml`` attribute)."""
    import xarray as xr  # lazy: xarray loads pandas; `import deapull` and readers of the contract alone skip it
    path = Path(path)
    if not path.is_file():
        return False
    try:
        with xr.open_dataset(path, engine=ENGINE) as ds:
            complete = int(ds.attrs.get("complete", 0)) == 1 and all(v in ds for v in REQUIRED)
            return complete and (scene_toml is None or ds.attrs.get("scene_toml") == scene_toml)
    except (OSError, ValueError):
        return False


@dataclass(frozen=True)
class Run:
    """What :func:`read` returns: the checked columns (float64) and the attributes."""
    path: Path
    columns: dict
    attrs: dict

    def number(self, name: str, positive: bool = True, default: float | None = None) -> float:
        """Attribute ``name`` as a finite number (> 0 when ``positive``, else >= 0).

        ``default`` is returned when the attribute is absent; without one a missing
        attribute is an error.
        """
        if name not in self.attrs:
            if default is not None:
                return default
            raise DatasetError(f"{self.path}: attribute {name!r} is missing")
        try:
            value = float(self.attrs[name])
        except (TypeError, ValueError):
            raise DatasetError(f"{self.path}: attribute {name!r} = {self.attrs[name]!r} is not a number") from None
        if not np.isfinite(value) or value < 0 or (value == 0 and positive):
            raise DatasetError(f"{self.path}: attribute {name!r} = {value!r} must be "
                               f"{'a positive' if positive else 'a non-negative'} number")
        return value


def read(path: str | os.PathLike, variables: Sequence[str] = REQUIRED, min_steps: int = 1,
         optional: Sequence[str] = ()) -> Run:
    """Open one dataset and check it against the contract.

    Parameters
    ----------
    path : path-like
    variables : names of the variables to return (each must be in :data:`VARIABLES`)
    min_steps : fewest points accepted
    optional : further variables returned, checked the same way, when the file has them

    Raises
    ------
    DatasetError
        When the file is missing or unreadable, is not marked complete, a variable is
        missing, has other dimensions than ``(step,)``, declares other units than the
        contract's or holds a non-finite value, or the run is shorter than ``min_steps``.
    """
    import xarray as xr  # lazy: xarray loads pandas; `import deapull` and readers of the contract alone skip it
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: no such dataset file")
    try:
        with xr.open_dataset(path, engine=ENGINE) as ds:
            ds.load()
    except (OSError, ValueError) as err:
        raise DatasetError(f"{path}: cannot read as netCDF/HDF5 ({err})") from err
    if int(ds.attrs.get("complete", 0)) != 1:
        raise DatasetError(f"{path}: attribute 'complete' is not 1: the FEM run did not finish")
    columns = {name: _variable(ds, path, name) for name in variables}
    columns.update({name: _variable(ds, path, name) for name in optional if name in ds.variables})
    n = len(next(iter(columns.values()))) if columns else ds.sizes.get(DIM, 0)
    if n < min_steps:
        raise DatasetError(f"{path}: variable {variables[0]!r}: {n} steps, need at least {min_steps}")
    return Run(path, columns, dict(ds.attrs))


def _variable(ds, path: Path, name: str) -> np.ndarray:
    units = VARIABLES[name][0]
    if name not in ds.variables:
        raise DatasetError(f"{path}: variable {name!r} is missing")
    var = ds[name]
    if var.dims != (DIM,):
        raise DatasetError(f"{path}: variable {name!r} has dimensions {var.dims}, expected ('{DIM}',)")
    found = var.attrs.get("units")
    if found != units:
        raise DatasetError(f"{path}: variable {name!r} has units {found!r}, expected {units!r}")
    values = np.asarray(var.values, dtype=np.float64)
    if not np.all(np.isfinite(values)):
        bad = int(np.flatnonzero(~np.isfinite(values))[0])
        raise DatasetError(f"{path}: variable {name!r} has a non-finite value ({values[bad]}) at step {bad}")
    return values
