"""Dataset aggregation (``deapull dagger``, deapull.workflows.dagger) on the FEM plant of the
test fixture's mesh: the controller's own FEM episodes join f_a's training data, and the
retrained f_a predicts a closed-loop FEM run that neither model trained on better than the
ramp-only f_a. Marked ``fem`` (dolfinx)."""
from __future__ import annotations

from pathlib import Path

import pytest

from tests.data.make_sweep import OVERRIDES

pytestmark = pytest.mark.fem


def test_aggregation_adds_the_closed_loop_runs_and_lowers_the_model_error_on_a_new_one(tmp_path, sweep_dir):
    """Broken once: the aggregated runs left out of the retraining (f_a(1) = f_a(0) retrained on
    the ramps alone): the transitions did not grow and the error did not fall."""
    from deapull.surrogate import store
    from deapull.surrogate.data import load_setup
    from deapull.surrogate.evaluate import evaluate
    from deapull.workflows import control, dagger
    settings = control.ControlConfig(policies=["mpc"], plants=control.parse_plants("fem:C1"), noises=[1e-5],
                                     out=tmp_path, episodes=1, max_steps=200, hold_steps=20, target_m=-0.4e-3,
                                     data=Path(sweep_dir), phi_prior="coins", mpc_approach_m=0.2e-3,
                                     overrides=list(OVERRIDES), progress=False)
    config = dagger.DaggerConfig(control=settings, data=Path(sweep_dir), train=["C3", "C4"], val="C5",
                                 out=tmp_path / "dagger", rounds=2, epochs=80)
    rows = dagger.run(config)
    assert len(rows) == 2 and rows[0]["new_runs"] == rows[1]["new_runs"] == 1
    first_run = load_setup(next((tmp_path / "dagger" / "runs").glob("C1_r0_*.nc")))
    assert rows[1]["train_runs"] == rows[0]["train_runs"] + 1
    assert rows[1]["train_transitions"] == rows[0]["train_transitions"] + first_run.n_steps - 1
    # a closed-loop run neither model trained on: the one f_a(1)'s MPC produced in round 1
    new_run = load_setup(next((tmp_path / "dagger" / "runs").glob("C1_r1_*.nc")))
    errors = {k: evaluate(store.load(tmp_path / "dagger" / "models" / k)[0], new_run).metrics["mae_x_m"]
              for k in ("r0", "r1")}
    print(errors, rows)
    assert errors["r1"] < errors["r0"]
    assert (tmp_path / "dagger" / "dagger.md").is_file()


@pytest.mark.parametrize("change, named", [
    (["--plant", "surrogate:C1"], "FEM plants only"),
    (["--rounds", "0"], "--rounds 0"),
    (["--train", "C3,C9"], "C9.nc not found"),
    (["--mpc-model", "{tmp}/nowhere"], "--mpc-model"),
    (["--mpc-standoff", "-1"], "--mpc-standoff"),
])
def test_bad_dagger_arguments_exit_2_naming_them_before_any_work(tmp_path, sweep_dir, capsys, change, named):
    from deapull.workflows.cli import main
    out = tmp_path / "out"
    argv = ["dagger", "--data", str(sweep_dir), "--train", "C3,C4", "--val", "C5", "--target-mm", "-0.4",
            "--out", str(out),
            *[a.format(tmp=tmp_path) for a in change]]
    assert main(argv) == 2
    assert named in capsys.readouterr().err
    assert not out.exists()
