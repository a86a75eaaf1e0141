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
    from deapull.control.mpc_policy import MPCConfig
    from deapull.workflows import control, dagger
    settings = control.ControlConfig(policies=["mpc"], plants=control.parse_plants("fem:C1"), noises=[1e-5],
                                     out=tmp_path, episodes=1, max_steps=200, hold_steps=20, target_m=-0.4e-3,
                                     data=Path(sweep_dir), phi_prior="coins", mpc=MPCConfig(approach_m=0.2e-3),
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
    (["--set", "mpc.standoff_stds=-1"], "mpc.standoff_stds = -1"),
    (["--model-kind", "nn"], "cannot plan"),
    (["--set", "mpc.estimator.innovation_window=-1"], "mpc.estimator.innovation_window = -1"),
    (["--preset", "nope"], "--preset 'nope'"),
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


def test_dagger_takes_the_fem_presets_mpc_and_set_mpc_changes_it():
    """``deapull dagger`` runs ``make control PRESET=fem``'s MPC by default (its [mpc] table, its
    fixed prior), another preset's with ``--preset``, and ``--set mpc.KEY=VALUE`` changes one setting;
    the scene's own --set keys pass through to the FEM plant. Broken once (the preset's [mpc] table
    not read): the window stayed 0 and the rate 0."""
    from deapull.workflows.cli import build_parser
    from deapull.workflows.cli_control import dagger_config
    parser = build_parser()
    fem = dagger_config(parser.parse_args(["dagger", "--out", "unused"])).control
    assert fem.mpc.estimator.innovation_window == 25 and fem.mpc.rate_V == 0.4 and fem.mpc.reach_gate is True
    assert fem.mpc_phi == "prior" and fem.phi_prior == "coins" and fem.mpc.standoff_stds == 2.0
    other = dagger_config(parser.parse_args(["dagger", "--out", "unused", "--preset", "surrogate", "--set",
                                             "mpc.estimator.innovation_window=5", "--set", "mesh.n_length=4"])).control
    assert other.mpc.estimator.innovation_window == 5 and other.mpc.reach_gate is False and other.mpc.rate_V == 0.0
    assert other.mpc_phi == "infer" and other.overrides == ["mesh.n_length=4"]


def test_aggregation_retrains_a_memory_f_a_as_a_memory_model(tmp_path, sweep_dir):
    """f_a with the tip's memory (f-memory, planning with the prior's median): every round
    retrains the same kind on the ramps and the closed-loop runs. Broken once: the kind taken
    from ``TrainConfig``'s default (f-coulomb) instead of the given model's: round 1's model
    was f-coulomb."""
    import json

    from deapull.surrogate import store
    from deapull.surrogate.data import load_sweep
    from deapull.surrogate.train import TrainConfig, train
    from deapull.workflows import control, dagger
    ramps = load_sweep(sweep_dir, ["C3", "C4", "C5"])
    first = train(TrainConfig(kind="f-memory", epochs=40, seed=0), [ramps["C3"], ramps["C4"]], ramps["C5"])
    store.save(first.model, tmp_path / "fa_mem", first.summary(), first.history)
    settings = control.ControlConfig(policies=["mpc"], plants=control.parse_plants("fem:C1"), noises=[1e-5],
                                     out=tmp_path, episodes=1, max_steps=120, hold_steps=20, target_m=-0.4e-3,
                                     data=Path(sweep_dir), phi_prior="coins", mpc_phi="prior",
                                     overrides=list(OVERRIDES), progress=False)
    config = dagger.DaggerConfig(control=settings, data=Path(sweep_dir), train=["C3", "C4"], val="C5",
                                 out=tmp_path / "dagger", rounds=2, epochs=40, model=tmp_path / "fa_mem")
    rows = dagger.run(config)
    assert rows[0]["new_runs"] == 1
    assert all(r["train_runs"] == 3 for r in rows[1:])   # round 1 (if the loop went on): 2 ramps + 1 run
    retrained = tmp_path / "dagger" / "models" / "r1" / "model.json"
    assert json.loads(retrained.read_text())["kind"] == "f-memory"
