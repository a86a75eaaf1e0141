"""Make the committed FEM fixture of the surrogate tests: ``tests/data/sweep/C1.nc .. C8.nc``.

The data are this project's own FEM: the shipped ``coin_pull`` scene at test size (an
8 × 1 hexahedral mesh, 4 mm coin mesh size; all eight setups, 722 points each, 0.47–0.69 mm
of coin travel), made by (from the repository root)

    OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 \\
    mpirun -n 2 .venv/bin/deapull sweep --scene coin_pull --out DIR \\
        --set mesh.n_length=8 --set mesh.n_width=1 --set mesh.coin_size_m=0.004 \\
        --set contact.slip_rate_regularisation_m_s=1e-4 --set time.placement_first_step=1.0 \\
        --set contact.quadrature_degree=4

and then trimmed and compressed into ``tests/data/sweep``: every file keeps all its
attributes and the variables the surrogate reads (``t x u V dt Fx Fy``), except ``C3.nc``,
which keeps every variable (the FEM's regression test compares a fresh run of C3 with it
to round-off). Values are copied bit for bit; the files are zlib-compressed (level 9,
byte shuffle) in HDF5's newest file format, about 330 kB for the eight.

Usage (``make test-data`` runs the first)::

    python tests/data/make_sweep.py                  # run the sweep (about a minute on 2 cores)
    python tests/data/make_sweep.py --from DIR       # only trim an existing sweep folder

The fixture changes only when the FEM's answer does; rerun this then and commit the files.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
sys.path.insert(0, str(REPO))
from tests.conftest import SHARP  # noqa: E402  (the scene file as it was when the fixture was made)
OUT = HERE / "sweep"
SETUPS = [f"C{i}" for i in range(1, 9)]
#: the test-size mesh of the sweep, on coin_pull as its file was then (SHARP: the sharp edge, the
#: 0.3 mm rim, the soft coin)
#: (eps_v, the placement's first step and the contact rule pinned to the scenes' defaults when
#: the fixture was made: the shipped eps_v = 1e-5 moves the test-size travels by ~4 % and the
#: surrogate tests' figures were set on these)
OVERRIDES = (*SHARP, "mesh.n_length=8", "mesh.n_width=1", "mesh.coin_size_m=0.004",
             "contact.slip_rate_regularisation_m_s=1e-4", "time.placement_first_step=1.0",
             "contact.quadrature_degree=4", "contact.penalty_N_m3=1120000000.0", "table.height_m=-1.0")
#: what every fixture file keeps: the surrogate's variables (deapull.surrogate.data.VARIABLES)
TRIMMED = ("t", "x", "u", "V", "dt", "Fx", "Fy")
#: the setups that keep every variable
FULL = ("C3",)
ENCODING = {"zlib": True, "complevel": 9, "shuffle": True}


def run_sweep(out: Path, ranks: int = 2) -> None:
    """The FEM sweep of the docstring into ``out``."""
    deapull = Path(sys.executable).with_name("deapull")
    cmd = ["mpirun", "-n", str(ranks), str(deapull), "sweep", "--scene", "coin_pull", "--out", str(out)]
    for o in OVERRIDES:
        cmd += ["--set", o]
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1")
    print("+", " ".join(cmd), flush=True)
    subprocess.run(cmd, check=True, cwd=REPO, env=env)


def trim(src: Path, dst: Path, keep_all: bool) -> None:
    """Copy the dataset ``src`` to ``dst``: the :data:`TRIMMED` variables (or all), every
    attribute, values bit for bit, compressed."""
    import h5netcdf
    import numpy as np
    import xarray as xr
    from deapull.io import atomic_write

    with xr.open_dataset(src, engine="h5netcdf") as ds:
        ds = ds.load()
    if not keep_all:
        missing = [v for v in TRIMMED if v not in ds]
        if missing:
            raise SystemExit(f"{src}: variables {missing} are missing")
        ds = ds[list(TRIMMED)]
    for var in ds.variables.values():
        var.encoding = {}
    def write(tmp):
        # xarray's own writer cannot choose the HDF5 format version; the newest one ('latest')
        # halves the per-variable metadata of these small files
        store = xr.backends.H5NetCDFStore(h5netcdf.File(tmp, "w", libver="latest"), mode="w")
        try:
            ds.dump_to_store(store, encoding={name: ENCODING for name in ds.variables})
        finally:
            store.close()
        with xr.open_dataset(tmp, engine="h5netcdf") as back:
            for name in ds.variables:
                assert np.array_equal(back[name].values, ds[name].values, equal_nan=True), f"{dst}: {name} changed"
            assert back.attrs.keys() == ds.attrs.keys(), f"{dst}: attributes changed"

    atomic_write(dst, write)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--from", dest="source", default=None,
                    help="an existing sweep folder with C1.nc .. C8.nc (default: run the sweep now)")
    ap.add_argument("--out", default=str(OUT), help=f"fixture folder (default {OUT.relative_to(REPO)})")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="deapull-sweep-") as tmp:
        source = Path(args.source) if args.source else Path(tmp)
        if not args.source:
            run_sweep(source)
        out = Path(args.out)
        total = 0
        for name in SETUPS:
            trim(source / f"{name}.nc", out / f"{name}.nc", keep_all=name in FULL)
            size = (out / f"{name}.nc").stat().st_size
            total += size
            print(f"{out / name}.nc: {size / 1e3:.0f} kB{' (every variable)' if name in FULL else ''}")
        print(f"{len(SETUPS)} files, {total / 1e3:.0f} kB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
