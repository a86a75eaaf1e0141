"""What built the page: package versions and the machine."""
from __future__ import annotations

import importlib
import importlib.metadata as md
import os
import platform

#: packages whose versions the provenance section lists: distribution name (module name if different)
VERSIONS = (("fenics-dolfinx", "dolfinx"), ("gmsh", "gmsh"), ("petsc4py", "petsc4py"), ("mpi4py", "mpi4py"),
            ("numpy", "numpy"), ("xarray", "xarray"), ("h5netcdf", "h5netcdf"), ("h5py", "h5py"),
            ("torch", "torch"), ("gymnasium", "gymnasium"), ("stable-baselines3", "stable_baselines3"),
            ("matplotlib", "matplotlib"), ("pillow", "PIL"), ("playwright", "playwright"))


def versions() -> dict:
    """The version of Python and of each package in :data:`VERSIONS` that is installed."""
    out = {"python": platform.python_version()}
    for dist, module in VERSIONS:
        try:
            out[dist] = md.version(dist)
            continue
        except md.PackageNotFoundError:
            pass
        try:
            out[dist] = str(getattr(importlib.import_module(module), "__version__", "?"))
        except Exception:   # noqa: BLE001 — a package that fails to import is "not installed" here
            continue
    return out


def machine() -> str:
    """The platform, CPU model, core count and memory of this machine, in one line."""
    mem = ""
    try:
        kb = int(next(line.split()[1] for line in open("/proc/meminfo") if line.startswith("MemTotal")))
        mem = f", {kb / 2 ** 20:.0f} GiB RAM"
    except (OSError, StopIteration, ValueError):
        pass
    cpu = platform.processor() or platform.machine()
    try:
        cpu = next(line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo") if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return f"{platform.platform()}, {cpu}, {os.cpu_count()} cores{mem}"
