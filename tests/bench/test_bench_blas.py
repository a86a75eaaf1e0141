"""``make bench-blas``: the two children really run on different BLAS libraries, and every
numeric factorisation is timed (a refactorisation that PETSc skipped would time as 0 s).

On the preview fidelity's mesh (6,228 dofs), one factorisation per package: about ten seconds.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[2] / "bench" / "bench_blas.py"


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench_blas")
    subprocess.run([sys.executable, str(BENCH), "--fidelity", "preview", "--repeats", "1", "--out", str(out)], check=True,
                   capture_output=True, text=True)
    return json.loads((out / "bench_blas.json").read_text())


def test_petsc_factorises_with_openblas_after_setup(result):
    """scripts/setup.sh installs libopenblas0-serial; without it PETSc falls back to the
    reference BLAS, whose factorisations are ~4x slower (docs/fem_accuracy.md)."""
    assert any("openblas" in path for path in result["system"]["blas"]), result["system"]["blas"]


def test_the_reference_child_loads_the_reference_blas(result):
    if "reference" not in result:
        pytest.skip("no reference BLAS folder on this machine")
    assert result["reference"]["blas"], "the reference child reported no BLAS"
    assert not any("openblas" in path for path in result["reference"]["blas"]), result["reference"]["blas"]


@pytest.mark.parametrize("package", ["mumps", "umfpack"])
def test_each_numeric_factorisation_is_timed(result, package):
    for row in ("system", "reference"):
        if row in result:
            assert result[row][package]["factorisation_s"] > 1e-4, (row, result[row][package])
