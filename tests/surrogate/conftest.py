"""The surrogate tests use the shared fixtures of tests/conftest.py (``sweep_dir``, ``sweep``,
``trained``, ``QUICK``): the committed FEM sweep of tests/data/sweep and small models
trained once per session. Nothing here needs dolfinx, gmsh or mpirun."""
from __future__ import annotations

from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
#: test setups lie partly outside the training setup's range: that warning is expected here
OUT_OF_RANGE = pytest.mark.filterwarnings("ignore::deapull.surrogate.rollout.OutOfRangeWarning")


def pytest_collection_modifyitems(config, items):
    for item in items:
        if HERE in Path(item.path).parents:
            item.add_marker(OUT_OF_RANGE)
