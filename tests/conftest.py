"""Shared fixtures: tiny meshes, an mpirun launcher."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from workflows import scene as scenes

REPO = Path(__file__).resolve().parents[1]
TINY_MESH = ("mesh.n_length=4", "mesh.n_width=1", "mesh.coin_size_m=0.004")


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
        return scenes.load(name, setup=setup, overrides=(*TINY_MESH, *overrides))
    return make
