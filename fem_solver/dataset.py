"""The FEM dataset of one run: an xarray Dataset on dimension ``step``, written atomically.

Variables follow the paper's Table I (``t x u V dt Fx Fy``) plus solver diagnostics,
each with ``units`` and ``long_name`` (CF style). Attributes carry the resolved scene,
setup parameters, mesh statistics, package versions, git commit and wall time. The file
is written to a temporary name in the same folder and renamed, so a file that exists is
complete (``complete = 1``).
"""
from __future__ import annotations

import os
import platform
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import xarray as xr

from fem_solver.stepping import StepRecord, as_arrays

ENGINE = "h5netcdf"

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
    "stick": ("1", "1 when the coin sticks on the ground"),
    "force_balance_residual_N": ("N", "residual of the coin's momentum balance with Coulomb friction"),
    "tip_ux": ("m", "mean x displacement of the DEA's free-end face"),
    "tip_uy": ("m", "mean y displacement of the DEA's free-end face"),
    "tip_uz": ("m", "mean z displacement of the DEA's free-end face"),
    "mean_abs_J_minus_1": ("1", "volume average of |J - 1| (incompressibility check)"),
    "volume_change": ("1", "relative change of the DEA's volume, (integral of J - V0) / V0"),
    "wall_time_s": ("s", "wall time of the step"),
}
REQUIRED = ("t", "x", "u", "V", "dt", "Fx", "Fy")
assert set(VARIABLES) == set(StepRecord.__dataclass_fields__)


def package_versions() -> dict[str, str]:
    import dolfinx
    import gmsh
    import petsc4py
    return {"version_python": platform.python_version(), "version_dolfinx": dolfinx.__version__,
            "version_gmsh": gmsh.__version__, "version_petsc4py": petsc4py.__version__,
            "version_numpy": np.__version__, "version_xarray": xr.__version__}


def git_commit() -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10,
                             cwd=Path(__file__).parent)
        return out.stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def to_dataset(records, attrs: dict) -> xr.Dataset:
    """Build the Dataset; refuses any non-finite value."""
    cols = as_arrays(records)
    data = {}
    for name, (units, long_name) in VARIABLES.items():
        values = cols[name]
        if not np.all(np.isfinite(values)):
            raise ValueError(f"variable {name!r} has non-finite values; refusing to write a dataset")
        data[name] = ("step", values, {"units": units, "long_name": long_name})
    ds = xr.Dataset(data, coords={"step": np.arange(len(records))})
    ds.attrs.update({k: _attr(v) for k, v in attrs.items()})
    ds.attrs["complete"] = 1
    return ds


def _attr(value):
    if isinstance(value, bool):
        return int(value)
    if value is None:
        return ""
    return value


def write_atomic(ds: xr.Dataset, path: str | os.PathLike) -> Path:
    """Write ``ds`` to ``path`` through a temporary file and a rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=".nc.tmp")
    os.close(fd)
    try:
        ds.to_netcdf(tmp, engine=ENGINE)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return path


def is_complete(path: str | os.PathLike) -> bool:
    """True when ``path`` is a readable dataset marked complete."""
    path = Path(path)
    if not path.is_file():
        return False
    try:
        with xr.open_dataset(path, engine=ENGINE) as ds:
            return int(ds.attrs.get("complete", 0)) == 1 and all(v in ds for v in REQUIRED)
    except (OSError, ValueError):
        return False
