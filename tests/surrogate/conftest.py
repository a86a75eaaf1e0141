"""Fixtures of the surrogate tests: the datasets, and small models trained once per session."""
from __future__ import annotations

import os
from pathlib import Path

import pytest
import torch

from surrogate.data import load_sweep
from surrogate.train import TrainConfig, train
from tests.conftest import mpirun

torch.set_num_threads(1)

#: small but real trainings: each kind once per session, shared by the tests
QUICK = {"f": dict(epochs=80), "f-coulomb": dict(epochs=80), "nn": dict(epochs=40),
         "lstm": dict(epochs=25, hidden=32, batch_size=64)}


#: the test-size FEM sweep: the shipped coin_pull scene on a coarse mesh (≈700 dofs, 722
#: points per setup, two stages, 0.47-0.69 mm of travel), all eight setups, mpirun -n 2
TEST_SWEEP = ("mesh.n_length=8", "mesh.n_width=1", "mesh.coin_size_m=0.004")


@pytest.fixture(scope="session")
def sweep_dir(tmp_path_factory):
    """Folder with C1.nc .. C8.nc made by the project's own FEM at test size (about a minute).

    ``DEAPULL_TEST_SWEEP=DIR`` reuses a folder made earlier with the same command.
    """
    reuse = os.environ.get("DEAPULL_TEST_SWEEP")
    if reuse:
        return Path(reuse)
    out = tmp_path_factory.mktemp("sweep")
    args = ["-m", "workflows", "sweep", "--scene", "coin_pull", "--out", str(out)]
    for o in TEST_SWEEP:
        args += ["--set", o]
    proc = mpirun(2, *args, timeout=1200)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out


@pytest.fixture(scope="session")
def sweep(sweep_dir):
    """The checked datasets of all eight setups, by name."""
    return load_sweep(sweep_dir, [f"C{i}" for i in range(1, 9)])


@pytest.fixture(scope="session")
def trained(sweep):
    """``trained(kind)``: a model of ``kind`` trained on C1 (validated on C2), cached."""
    cache = {}

    def get(kind: str):
        if kind not in cache:
            cache[kind] = train(TrainConfig(kind=kind, **QUICK[kind]), [sweep["C1"]], sweep["C2"])
        return cache[kind]
    return get


def pytest_configure(config):
    """Test setups lie partly outside the training setup's range: that warning is expected here."""
    config.addinivalue_line("filterwarnings", "ignore::surrogate.rollout.OutOfRangeWarning")
