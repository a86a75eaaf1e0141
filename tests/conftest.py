"""Shared fixtures: tiny meshes, an mpirun launcher; the ``fem`` marker.

The tests mirror the packages (tests/<package>/ tests deapull.<package>). Every test under
tests/meshing/ and tests/fem_solver/ is marked ``fem`` (it needs gmsh and dolfinx), as is
any module elsewhere that sets ``pytestmark = pytest.mark.fem``. ``pytest -m "not fem"``
runs the rest on a machine without FEniCSx; there the FEM folders are not even collected.
"""
from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

# The in-session trainings (the ``trained`` fixture) are chaotic in the last bits: the same seed
# gives other weights on an AVX-512 Intel than on an AVX2 AMD, and tests tuned on one failed on
# the other. Pinning the code paths of torch's own kernels (ATEN_CPU_CAPABILITY), of MKL's BLAS
# (conditional numerical reproducibility) and of oneDNN's LSTM (at most AVX2) makes a training
# the same on those two machines, not on every CPU (an AVX-512 AMD trains other weights again), so
# the tests written for particular weights load committed models (the ``committed`` fixture). The
# pins must be set before torch loads (tests/test_reproducible.py checks them).
if "torch" in sys.modules:
    raise RuntimeError("tests/conftest.py must pin torch's code paths before torch is imported")
os.environ.setdefault("ATEN_CPU_CAPABILITY", "default")
os.environ.setdefault("MKL_CBWR", "COMPATIBLE")
os.environ.setdefault("ONEDNN_MAX_CPU_ISA", "AVX2")

import pytest  # noqa: E402

from deapull import scene as scenes  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DATA = Path(__file__).resolve().parent / "data"
#: test folders whose every test needs gmsh and dolfinx
FEM_FOLDERS = ("meshing", "fem_solver")
HAVE_FEM = all(importlib.util.find_spec(m) is not None for m in ("dolfinx", "gmsh"))


def _fem_folder(path: Path) -> bool:
    parts = Path(path).resolve().relative_to(REPO / "tests").parts
    return len(parts) > 1 and parts[0] in FEM_FOLDERS


def pytest_ignore_collect(collection_path, config):
    """Without FEniCSx the FEM folders are skipped at collection (their imports need it)."""
    if not HAVE_FEM and collection_path.is_relative_to(REPO / "tests") and _fem_folder(collection_path):
        return True
    return None


def pytest_collection_modifyitems(config, items):
    for item in items:
        if _fem_folder(item.path):
            item.add_marker(pytest.mark.fem)
TINY_MESH = ("mesh.n_length=4", "mesh.n_width=1", "mesh.coin_size_m=0.004")
#: coin_pull and coin_release as their files were before the rounded geometry and the data fidelity became
#: the file: the 20 mm wide DEA with the coin 3 mm inboard, the sharp free edge, a 0.3 mm circular rim, no
#: tip zone or rim band, the soft coin, 5 x 5 contact points, a fresh Jacobian at 0.3, Newton to 1e-8 N
#: (the fast meshes that the FEM's machinery tests are written for; each test names what it changes)
SHARP = ("dea.width_m=0.02", "coin.center_from_tip_m=0.003", "solver.jacobian_reuse_ratio=0.3",
         "dea.free_edge_radius_m=0.0", "coin.edge_radius_m=0.0003", "coin.edge_shape='circular'",
         "mesh.tip_zone_m=0.0", "mesh.rim_band_width_m=0.0", "mesh.rim_band_m=[]", "mesh.free_edge_divisions=2",
         "mesh.n_length=16",
         "mesh.n_passive=1", "contact.quadrature_degree=8", "contact.penalty_N_m3=2.24e9", "table.penalty_N_m3=1e11",
         "solver.linear_solver='umfpack'", "solver.coupling_tol_m=1e-10", "solver.newton_atol=1e-8")
COIN_SCENES = ("coin_pull", "coin_release")


def mpirun(n: int, *args: str, timeout: float = 600) -> subprocess.CompletedProcess:
    """Run ``python *args`` under ``mpirun -n n`` and return the finished process."""
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1")
    cmd = ["mpirun", "-n", str(n), sys.executable, *args]
    return subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=timeout, cwd=REPO)


@pytest.fixture
def tiny_scene():
    """Load a shipped scene on a tiny mesh, with extra overrides."""
    def make(name: str, *overrides: str, setup=None):
        sharp = SHARP if name in COIN_SCENES else ()
        return scenes.load(name, setup=setup, overrides=(*sharp, *TINY_MESH, *overrides))
    return make


# --- the surrogate's FEM fixture and trained models (tests/surrogate, tests/workflows) -------
# No dolfinx, gmsh or mpirun: the datasets are committed under tests/data/sweep, made by
# this project's FEM (tests/data/make_sweep.py states the command; `make test-data`
# regenerates them). torch is imported inside the fixtures, so FEM tests never load it.

#: the committed test sweep: the shipped coin_pull scene on an 8 × 1 hexahedral mesh, all
#: eight setups (722 points each, two stages, 0.47–0.69 mm of travel)
SWEEP = DATA / "sweep"
#: the control tests' models, trained once on SWEEP and committed (tests/data/make_models.py)
MODELS = DATA / "models"
#: small but real trainings: each kind once per session, shared by the tests
QUICK = {"f": dict(epochs=80), "f-coulomb": dict(epochs=80), "f-memory": dict(epochs=80), "f-patch": dict(epochs=80),
         "f-patch-lag": dict(epochs=80), "nn": dict(epochs=40),
         "lstm": dict(epochs=25, hidden=32, batch_size=64)}


@pytest.fixture(scope="session")
def sweep_dir():
    """Folder with C1.nc .. C8.nc made by the project's own FEM at test size (committed).

    ``DEAPULL_TEST_SWEEP=DIR`` uses another folder made with the same command (see
    tests/data/make_sweep.py). Tests read it and never write into it.
    """
    folder = Path(os.environ.get("DEAPULL_TEST_SWEEP") or SWEEP)
    missing = [f"C{i}.nc" for i in range(1, 9) if not (folder / f"C{i}.nc").is_file()]
    if missing:
        pytest.fail(f"{folder}: test sweep incomplete (missing {', '.join(missing)}); run `make test-data`")
    return folder


@pytest.fixture(scope="session")
def sweep(sweep_dir):
    """The checked datasets of all eight setups, by name."""
    from deapull.surrogate.data import load_sweep
    return load_sweep(sweep_dir, [f"C{i}" for i in range(1, 9)])


@pytest.fixture(scope="session")
def trained(sweep):
    """``trained(kind)``: a model of ``kind`` trained on C1 (validated on C2), cached."""
    import torch

    from deapull.surrogate.train import TrainConfig, train
    torch.set_num_threads(1)
    cache = {}

    def get(kind: str):
        if kind not in cache:
            cache[kind] = train(TrainConfig(kind=kind, **QUICK[kind]), [sweep["C1"]], sweep["C2"])
        return cache[kind]
    return get


@pytest.fixture(scope="session")
def committed():
    """``committed(kind)``: the committed model of ``kind`` (f-coulomb, f-memory, f-patch), cached.

    The ``trained`` fixture's training, run once and committed in tests/data/models
    (tests/data/make_models.py): the control tests are written for these weights, which a
    training in the session reproduces only on CPUs like the one that made them."""
    from deapull.surrogate import store
    cache = {}

    def get(kind: str):
        if kind not in cache:
            if not (MODELS / kind).is_dir():
                pytest.fail(f"{MODELS / kind}: no committed model of {kind!r}; run `make test-data`")
            cache[kind] = store.load(MODELS / kind)[0]
        return cache[kind]
    return get
