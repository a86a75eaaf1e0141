#!/usr/bin/env bash
# One-command set-up on Debian 12: apt packages (FEniCSx 0.5.2, gmsh, MPI), the project's
# venv on Debian's python3 with --system-site-packages, torch 2.13.0 (CPU) and the project.
# Idempotent: each step checks first, so a second run takes seconds.
set -euo pipefail
cd "$(dirname "$0")/.."

# libopenblas0-serial: PETSc's MUMPS and UMFPACK factorise with the BLAS that libblas.so.3 points at,
# the reference (netlib) BLAS unless an optimised one is installed; OpenBLAS (one thread, so mpirun
# ranks do not oversubscribe) factorises the resolved Jacobian 3.8x faster (make bench-blas)
APT_PACKAGES="python3-dolfinx python3-gmsh python3-mpi4py python3-petsc4py python3-meshio python3-h5py python3-venv openmpi-bin make libopenblas0-serial"
SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"

missing=""
for p in $APT_PACKAGES; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing="$missing $p"
done
if [ -n "$missing" ]; then
    echo "[setup] apt-get install:$missing"
    $SUDO apt-get update -q
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q --no-install-recommends $missing
fi

if [ ! -x .venv/bin/python ]; then
    echo "[setup] creating .venv from /usr/bin/python3 (--system-site-packages)"
    /usr/bin/python3 -m venv --system-site-packages .venv
fi

# Debian's petsc4py/dolfinx are built against Debian's numpy: keep that exact numpy.
NUMPY=$(/usr/bin/python3 -c 'import numpy; print(numpy.__version__)')
echo "numpy==$NUMPY" > .venv/constraints.txt
stamp=.venv/.deapull-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ] || [ scripts/setup.sh -nt "$stamp" ]; then
    echo "[setup] pip install (torch 2.13.0 CPU wheel, project in editable mode)"
    .venv/bin/pip install -q -c .venv/constraints.txt "torch==2.13.0" -e ".[test]"
    touch "$stamp"
fi
.venv/bin/python -c "import dolfinx, gmsh, torch, xarray; print(f'[setup] ok: dolfinx {dolfinx.__version__}, gmsh {gmsh.__version__}, torch {torch.__version__}')"
