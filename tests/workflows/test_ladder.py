"""Surrogates on the FEM fidelity ladder: a rollout row compared with the reference like a rung."""
from __future__ import annotations

import shutil
import subprocess
import sys

import numpy as np
import pytest

from deapull import dataset
from deapull.surrogate import store
from deapull.surrogate.evaluate import evaluate
from deapull.workflows import fidelity, ladder
from tests.conftest import REPO

pytestmark = pytest.mark.filterwarnings("ignore::deapull.surrogate.rollout.OutOfRangeWarning")


def test_surrogate_rows_are_compared_with_the_reference(sweep_dir, sweep, trained, tmp_path):
    for kind in ("f-coulomb", "nn"):
        store.save(trained(kind).model, tmp_path / "models" / kind)
    models = ladder.load_models([tmp_path / "models" / "f-coulomb", tmp_path / "models" / "nn"])
    rows = ladder.ladder_rows(models, sweep_dir, "C3", tmp_path)
    assert [r["case"] for r in rows] == ["surrogate-f-coulomb", "surrogate-nn"]
    assert all(r["kind"] == "surrogate" and r["solve_s"] > 0 and (tmp_path / r["dataset"]).is_file() for r in rows)
    # the rollout files follow the dataset contract (names, units, complete) for what they hold:
    # t, x and, from an f = d∘m, Fy (a black box predicts no force)
    written = dataset.read(tmp_path / rows[0]["dataset"], ("t", "x", "Fy"))
    assert np.array_equal(written.columns["t"], sweep["C3"].t)
    with pytest.raises(dataset.DatasetError, match="'Fy' is missing"):
        dataset.read(tmp_path / rows[1]["dataset"], ("t", "x", "Fy"))
    # the FEM run of C3 itself as the reference: the row's error is the model's error on C3
    (tmp_path / "cases" / "ref").mkdir(parents=True)
    shutil.copy(sweep_dir / "C3.nc", tmp_path / "cases" / "ref" / "C3.nc")
    ref = {"case": "ref", "kind": "fem", "status": "ok", "is_reference": True, "solve_s": 10.0,
           "dataset": "cases/ref/C3.nc", "poisson_ratio": 0.5}
    out = {r["case"]: r for r in fidelity.add_errors([ref, *rows], tmp_path)}
    for kind in ("f-coulomb", "nn"):
        ev = evaluate(trained(kind).model, sweep["C3"])
        mae_x_mm = 1e3 * np.abs(ev.x_model - ev.x_fem).mean()     # over all points, as the ladder does
        assert out[f"surrogate-{kind}"]["mae_x_mm"] == pytest.approx(mae_x_mm, rel=1e-6)
        assert not out[f"surrogate-{kind}"]["on_pareto"], "the Pareto front is the FEM rungs'"
    assert np.isfinite(out["surrogate-f-coulomb"]["mae_Fy_mN"]) and np.isnan(out["surrogate-nn"]["mae_Fy_mN"])


@pytest.mark.fem   # the fidelity command runs under MPI (mpi4py)
def test_fidelity_refuses_a_missing_surrogate_before_any_solve(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "deapull.workflows", "fidelity", "--out", str(tmp_path / "f"),
                           "--surrogate", str(tmp_path / "nowhere")], cwd=REPO, capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 2 and "nowhere" in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "f" / "cases").exists()
