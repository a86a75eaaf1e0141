"""``deapull control``: bad arguments exit 2 with one line naming the argument before any
work; a run writes the CSV, the table beside the paper's numbers and the figures; (``fem``)
a short episode on the FEM plant of a tiny mesh."""
from __future__ import annotations

import csv
import json
from dataclasses import replace
from pathlib import Path

import pytest

from deapull.workflows.cli import main
from tests.conftest import SHARP, TINY_MESH


def _rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@pytest.fixture
def base(tmp_path, sweep_dir, fs1_dir):
    """Arguments of a valid surrogate run (the fixture's model and data)."""
    return ["control", "--plant", "surrogate:C1", "--data", str(sweep_dir), "--plant-model", str(fs1_dir),
            "--out", str(tmp_path / "out"), "--no-progress"]


@pytest.mark.parametrize("change, named", [
    (["--policy", "lqr"], "--policy 'lqr'"),
    (["--plant", "mujoco:C1"], "--plant 'mujoco:C1'"),
    (["--plant", "surrogate:C9"], "unknown setup 'C9'"),
    (["--plant", "surrogate"], "--plant 'surrogate'"),
    (["--noise=-1e-4"], "--noise '-1e-4'"),
    (["--noise", "0,-0.001"], "--noise '-0.001'"),
    (["--noise", "loud"], "--noise 'loud'"),
    (["--plant-model", "{tmp}/nowhere"], "--plant-model"),
    (["--data", "{tmp}"], "--data"),
    (["--episodes", "0"], "--episodes 0"),
    (["--dv-max", "0"], "--dv-max 0"),
    (["--target-mm", "1"], "--target-mm 1"),
    (["--max-steps", "-3"], "--max-steps -3"),
    (["--threads", "0"], "--threads 0"),
    (["--reach-fraction", "1.5"], "--reach-fraction 1.5"),
])
def test_bad_arguments_exit_2_with_one_line_naming_them_before_any_work(base, tmp_path, capsys, change, named):
    argv = [*base, "--policy", "pd"] + [c.replace("{tmp}", str(tmp_path)) for c in change]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and named in err, err
    assert not (tmp_path / "out").exists()                 # refused before any output


@pytest.mark.parametrize("change, named", [
    (["--mpc-model", "{tmp}/nowhere"], "--mpc-model"),
    (["--set", "mpc.cost='lavish'"], "mpc.cost = 'lavish'"),
    (["--phi-prior", "flat"], "--phi-prior 'flat'"),
    (["--set", "mpc.rate_V=nan"], "mpc.rate_V = nan"),
    (["--set", "mpc.creep_V=0"], "mpc.creep_V = 0"),
    (["--set", "mpc.recentre=1"], "mpc.recentre: unknown key"),
    (["--set", "mpc.estimator.innovation_window=-5"], "mpc.estimator.innovation_window = -5"),
    (["--set", "mpc.inference.loss='roll'"], "mpc.inference.loss = 'roll'"),
    (["--set", "mpc.standoff_stds=two"], "mpc.standoff_stds = 'two': expected float"),
])
def test_bad_mpc_arguments_exit_2(base, tmp_path, capsys, fs1_dir, change, named):
    argv = [*base, "--policy", "mpc", "--mpc-model", str(fs1_dir)] + [c.replace("{tmp}", str(tmp_path)) for c in change]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and named in err, err


def test_mpc_runs_through_the_harness_and_reports_its_inference(base, tmp_path, fs1_dir):
    """Three iterations of the MPC (deapull.control.mpc_policy) on the fixture's plant: the row
    carries its inferred φ and its own plan and inference times, and the inferred-φ figure
    is drawn (the MPC itself is tested in test_mpc.py)."""
    out = tmp_path / "out"
    argv = [*base, "--policy", "mpc", "--mpc-model", str(fs1_dir), "--episodes", "1", "--max-steps", "3",
            "--hold", "0", "--target-mm", "-0.4"]
    assert main(argv) == 0
    (row,) = _rows(out / "control.csv")
    assert row["policy"] == "mpc" and row["steps_run"] == "3"
    assert float(row["inferred_mass_kg"]) > 0 and float(row["inferred_mu_b"]) > 0
    assert float(row["solve_ms_per_iteration"]) > 0 and float(row["inference_ms_per_iteration"]) > 0
    assert (out / "inferred_surrogate_C1_noise0.png").is_file()


def test_filtered_policies_run_under_their_own_names(base, tmp_path, capsys, fs1_dir):
    """``pd+kf`` and ``mpc+kf`` (deapull.control.filters) go through the harness as policies
    of their own, beside the paper's numbers of PD and MPC."""
    out = tmp_path / "out"
    argv = [*base, "--policy", "pd+kf,mpc+kf", "--mpc-model", str(fs1_dir), "--episodes", "1", "--max-steps", "3",
            "--hold", "0", "--target-mm", "-0.4", "--noise", "1e-5"]
    assert main(argv) == 0
    assert "~1,500" in capsys.readouterr().out
    rows = _rows(out / "control.csv")
    assert [r["policy"] for r in rows] == ["pd+kf", "mpc+kf"] and all(r["steps_run"] == "3" for r in rows)


def test_control_run_writes_csv_table_and_figures(base, tmp_path, capsys, fs1_dir, sweep_dir):
    out = tmp_path / "out"
    argv = [*base, "--policy", "pd,heur", "--episodes", "2", "--noise", "0,1e-5", "--target-mm", "-0.4",
            "--max-steps", "700", "--hold", "20"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "paper: iterations" in printed and "~1,500" in printed and "~500" in printed
    rows = _rows(out / "control.csv")
    assert len(rows) == 8 and {r["policy"] for r in rows} == {"pd", "heur"}
    assert {(r["noise_std_m"], r["seed"]) for r in rows} == {(n, s) for n in ("0.0", "1e-05") for s in ("0", "1")}
    for column in ("iterations_to_target", "settled", "final_abs_error_m", "ms_per_iteration", "true_mass_kg",
                   "inferred_mass_kg"):
        assert column in rows[0]
    heur = [r for r in rows if r["policy"] == "heur"]
    assert all(r["reached"] == "True" and 300 < int(r["iterations_to_target"]) < 700 for r in heur)
    assert all(r["settled"] == "False" for r in heur)      # the ramp goes on through the window
    assert (out / "table.md").read_text().count("\n") == 2 + 4
    for stem in ("position", "voltage"):
        for noise in ("0", "1e-05"):
            assert (out / f"{stem}_surrogate_C1_noise{noise}.png").stat().st_size > 10_000
    assert (out / "traces.npz").is_file() and (out / "run.json").is_file()
    # the results file names the commit that ran it, as run.json does, and the files it read
    from deapull import provenance
    summary = json.loads((out / "summary.json").read_text())
    assert summary["git_commit"] == provenance.git_commit()
    assert summary["inputs"] == {"models": {str(fs1_dir): provenance.file_sha256(fs1_dir / "model.pt")},
                                 "datasets": {"C1": provenance.file_sha256(sweep_dir / "C1.nc")}}


def test_an_interrupted_run_keeps_the_episodes_it_finished(base, tmp_path, monkeypatch):
    from deapull.workflows import control as workflow
    real, calls = workflow.run_episode, []

    def stopped_in_the_second(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(workflow, "run_episode", stopped_in_the_second)
    with pytest.raises(KeyboardInterrupt):
        main([*base, "--policy", "pd", "--episodes", "2", "--target-mm", "-0.4", "--max-steps", "700", "--hold", "20"])
    out = tmp_path / "out"
    rows = _rows(out / "control.csv")
    assert [(r["policy"], r["seed"]) for r in rows] == [("pd", "0")]
    assert (out / "traces.npz").is_file() and (out / "table.md").is_file() and not list(out.glob("*.png"))


@pytest.mark.fem
def test_control_on_the_fem_plant_of_a_tiny_mesh(tmp_path):
    out = tmp_path / "out"
    argv = ["control", "--policy", "heur", "--plant", "fem:C1", "--episodes", "1", "--max-steps", "5", "--hold", "0",
            "--out", str(out), "--no-progress", *[a for s in (*SHARP, *TINY_MESH) for a in ("--set", s)]]
    assert main(argv) == 0
    (row,) = _rows(out / "control.csv")
    assert row["plant"] == "fem:C1" and row["status"] == "ok" and row["steps_run"] == "5"
    assert float(row["final_V_V"]) == pytest.approx(2.5) and float(row["true_mass_kg"]) > 1e-3
    assert (out / "fem" / "C1" / "mesh").is_dir()


def test_reach_fraction_gives_each_fem_plant_its_share_of_its_own_ramp_travel(sweep_dir):
    """--reach-fraction 0.8 (G5's task): fem:C1 and fem:C5 each aim at 0.8 of their dataset's
    travel, so the fixture's slower coin C5 gets a nearer target; a surrogate plant keeps the
    target, and setpoints win over it."""
    from deapull.surrogate.data import load_setup
    from deapull.workflows import control as workflow
    config = workflow.ControlConfig(policies=["heur"], plants=workflow.parse_plants("fem:C1,fem:C5,surrogate:C2"), noises=[0.0],
                                    out=Path("unused"), data=Path(sweep_dir), reach_fraction=0.8)
    targets = workflow.plant_targets(config)
    for setup in ("C1", "C5"):
        assert targets[setup] == pytest.approx(0.8 * float(load_setup(Path(sweep_dir) / f"{setup}.nc").x.min()))
    assert targets["C5"] > targets["C1"] and "C2" not in targets        # a surrogate plant keeps --target-mm
    assert workflow.plant_targets(replace(config, setpoints_m=[-4e-4])) == {}


def test_a_target_beyond_the_plants_reach_exits_2_and_is_never_moved(base, tmp_path, capsys):
    """The fixture's surrogate C1 slides ~0.5 mm under the full ramp: -0.4 mm runs, -5 mm is
    refused before any episode with the reach in the message."""
    assert main([*base, "--policy", "heur", "--episodes", "1", "--max-steps", "5", "--hold", "0",
                 "--target-mm", "-0.4"]) == 0
    capsys.readouterr()
    assert main([*base, "--policy", "heur", "--target-mm", "-5", "--out", str(tmp_path / "far")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--target-mm -5: surrogate:C1 cannot reach it" in err, err
    reach_mm = float(err.split("gets to ")[1].split(" mm")[0])
    assert -1.0 < reach_mm < -0.4
    assert not (tmp_path / "far" / "control.csv").exists()


def test_an_unreachable_surrogate_plant_is_reported_and_the_others_run(base, tmp_path, capsys):
    """``--unreachable report`` for surrogate plants too: C5's coin (μ_b 0.25 on the fixture's
    f_s) gets less far under the fastest push than C1's, so a target between the two reaches is a
    row "unreachable" for surrogate:C5 while surrogate:C1 runs; with only C5 the run exits 2.
    Broken once: the reach checked inside the episode loop with "refuse" semantics (exit 2)."""
    reach = {}
    for setup in ("C1", "C5"):
        argv = [*base, "--plant", f"surrogate:{setup}", "--policy", "heur", "--target-mm", "-5"]
        assert main(argv) == 2
        reach[setup] = float(capsys.readouterr().err.split("gets to ")[1].split(" mm")[0])
    assert reach["C5"] > reach["C1"] + 0.05, reach               # C5's coin gets less far
    target = f"{0.5 * (reach['C1'] + reach['C5']):.4f}"
    out = tmp_path / "report"
    argv = [*base, "--plant", "surrogate:C1,surrogate:C5", "--policy", "heur", "--episodes", "1", "--max-steps", "5",
            "--hold", "0", "--target-mm", target, "--unreachable", "report", "--out", str(out)]
    assert main(argv) == 0
    rows = {r["plant"]: r for r in _rows(out / "control.csv")}
    assert rows["surrogate:C5"]["status"].startswith(f"unreachable: --target-mm {float(target):g}: surrogate:C5 "
                                                     "cannot reach it")
    assert rows["surrogate:C5"]["steps_run"] == "0" and rows["surrogate:C1"]["status"] == "ok"
    assert int(rows["surrogate:C1"]["steps_run"]) > 0
    argv[argv.index("surrogate:C1,surrogate:C5")] = "surrogate:C5"
    argv[argv.index(str(out))] = str(tmp_path / "none")
    assert main(argv) == 2 and "no plant can reach the task" in capsys.readouterr().err
    assert not (tmp_path / "none" / "control.csv").exists()


def test_the_papers_adam_and_lm_are_both_reachable_from_the_cli(base, tmp_path, fs1_dir, capsys):
    for optimizer in ("adam", "lm"):
        out = tmp_path / optimizer
        argv = [*base, "--policy", "mpc", "--mpc-model", str(fs1_dir), "--episodes", "1", "--max-steps", "3",
                "--hold", "0", "--target-mm", "-0.4", "--set", f"mpc.inference.optimizer='{optimizer}'", "--out",
                str(out)]
        assert main(argv) == 0
        assert json.loads((out / "run.json").read_text())["config"]["mpc"]["inference"]["optimizer"] == optimizer
    assert main([*base, "--policy", "mpc", "--set", "mpc.inference.optimizer='sgd'", "--out", str(tmp_path / "x")]) == 2
    assert "inference optimizer 'sgd'" in capsys.readouterr().err


def test_the_fixed_prior_mpc_infers_nothing_and_needs_the_prior(base, tmp_path, fs1_dir, capsys):
    """``--mpc-phi prior`` plans with the coin-family prior's median (what the inference is
    compared with): its episodes carry no inferred φ; without ``--phi-prior coins`` it exits 2
    naming both options."""
    argv = base + ["--policy", "mpc", "--mpc-model", str(fs1_dir), "--episodes", "1", "--max-steps", "3", "--hold",
                   "0", "--target-mm", "-0.4"]
    assert main(argv + ["--phi-prior", "coins", "--set", "control.mpc_phi='prior'"]) == 0
    (row,) = _rows(tmp_path / "out" / "control.csv")
    assert row["inferred_mass_kg"] == "" and row["inference_ms_per_iteration"] == ""
    capsys.readouterr()
    assert main(argv + ["--set", "control.mpc_phi='prior'"]) == 2
    err = capsys.readouterr().err
    assert "mpc_phi = 'prior'" in err and "--phi-prior coins" in err


def test_the_reach_gate_setting_reaches_the_run(base, tmp_path, fs1_dir):
    """``--set mpc.reach_gate=false`` switches the gate off in the run (run.json names it); without it
    the gate is on. The policy's side is tested in tests/control/test_mpc.py. Broken once (the setting
    not passed to the config): run.json said true."""
    argv = base + ["--policy", "mpc", "--mpc-model", str(fs1_dir), "--episodes", "1", "--max-steps", "3", "--hold",
                   "0", "--target-mm", "-0.4"]
    for flags, gate in (([], True), (["--set", "mpc.reach_gate=false"], False)):
        assert main(argv + flags) == 0
        assert json.loads((tmp_path / "out" / "run.json").read_text())["config"]["mpc"]["reach_gate"] is gate


def test_the_inference_engine_is_chosen_from_the_cli(base, tmp_path, trained, monkeypatch, capsys):
    """``mpc.inference.engine`` torch|native reaches the MPC's inference (the same estimates either way);
    ``native`` with a kind that has no compiled inference (the paper's law) exits 2 before any
    model loads, naming the flag. Broken once (then restored): ``mpc_settings`` not passing the
    engine on; the spy saw "auto" for both runs and the test failed."""
    from deapull.control import inference
    from deapull.surrogate import store
    seen = []
    real = inference.OnlineInference.__init__

    def spy(self, model, config=inference.InferenceConfig(), dt=1e-3):
        seen.append(config.engine)
        real(self, model, config, dt)
    monkeypatch.setattr(inference.OnlineInference, "__init__", spy)
    rows = {}
    for engine in ("torch", "native"):
        out = tmp_path / engine
        argv = [*base, "--policy", "mpc", "--mpc-model", base[base.index("--plant-model") + 1], "--episodes", "1",
                "--max-steps", "120", "--hold", "0", "--target-mm", "-0.4", "--set", f"mpc.inference.engine='{engine}'",
                "--out", str(out)]
        assert main(argv) == 0
        assert json.loads((out / "run.json").read_text())["config"]["mpc"]["inference"]["engine"] == engine
        rows[engine] = _rows(out / "control.csv")[0]
    assert seen == ["torch", "native"]
    # the two engines agree to round-off (the estimates differ in the last bits, and so the plans)
    assert float(rows["torch"]["final_x_m"]) == pytest.approx(float(rows["native"]["final_x_m"]), rel=1e-6)
    assert float(rows["torch"]["inferred_mu_b"]) != inference.INITIAL["mu_b"]          # the estimate moved
    for field in ("inferred_mass_kg", "inferred_mu_b", "inferred_mu_t"):
        assert float(rows["native"][field]) == pytest.approx(float(rows["torch"][field]), rel=1e-6), field
    result = trained("f")
    paper = store.save(result.model, tmp_path / "paper_f", result.summary(), result.history)
    out = tmp_path / "refused"
    argv = [*base, "--policy", "mpc", "--mpc-model", str(paper), "--set", "mpc.inference.engine='native'", "--out",
            str(out)]
    assert main(argv) == 2
    assert "mpc.inference.engine = 'native'" in capsys.readouterr().err and not out.exists()


def test_the_tables_bound_column_sums_each_reached_episodes_bound_at_the_tasks_tolerance():
    from deapull.workflows.control_outputs import summary_rows
    row = dict(policy="mpc", plant="surrogate:C1", noise_std_m=1e-4, setpoints_mm="-1", settled=False,
               overshoot_m=0.0, final_abs_error_m=0.0, ms_per_iteration=1.0, training_steps=None)
    rows = [dict(row, reached=True, iterations_to_target=100), dict(row, reached=True, iterations_to_target=384),
            dict(row, reached=False, iterations_to_target=None)]
    # erf(w sqrt(N) / (sigma sqrt 2)): 0.683 at N = 100 and 0.950 at N = 384 for w = 10 um, sigma = 0.1 mm
    assert summary_rows(rows, 1e-5)[0]["bound"] == "1.6/3"
    assert summary_rows(rows, 2e-5)[0]["bound"] == "2.0/3", "the task's tolerance, not a fixed one"


def test_the_results_file_counts_episode_one_apart_and_the_docs_judge_the_goals_from_it():
    from deapull.workflows.control_outputs import summary_counts, summary_rows
    from deapull.workflows.docs_tables import control_goals
    row = dict(policy="mpc", plant="surrogate:C1", noise_std_m=1e-4, setpoints_mm="-1", overshoot_m=0.0,
               final_abs_error_m=0.0, ms_per_iteration=1.0, training_steps=None)
    rows = [dict(row, episode=0, reached=True, settled=True, iterations_to_target=400),
            dict(row, episode=1, reached=True, settled=True, iterations_to_target=80),
            dict(row, episode=2, reached=True, settled=False, iterations_to_target=70),
            dict(row, episode=3, reached=True, settled=True, iterations_to_target=90)]
    (g,) = summary_counts(rows)
    assert (g["episodes"], g["settled"], g["settled_within_100"], g["later_episodes"], g["later_settled"]) == (4, 3, 2, 3, 2)
    assert g["later_median_iterations"] == 85 and g["median_iterations"] == 85
    assert summary_rows(rows, 1e-5)[0]["first"] == "settled in 400" and summary_rows(rows, 1e-5)[0]["later"] == "2/3, 85"
    text = control_goals({"groups": [g]})
    assert "G2 at 1e-4: settled 3/4, medians 90, within 100 iterations 2/4 (goal 4/4" in text and "not met" in text
    assert "G3 at 1e-4, episodes 2–N: settled 2/3, medians 85 (goal all, median ≤ 100: not met)" in text
    assert "G1 at noise 0.0001: surrogate:C1 reached 4/4, median 85 (goal 10/10, median ≤ 100: met)" in text


def _parsed(*argv):
    from deapull.workflows.cli import build_parser
    from deapull.workflows.cli_control import apply_preset
    args = build_parser().parse_args(["control", *argv])
    apply_preset(args, args.parser)
    return args


def test_a_preset_sets_the_options_that_flags_and_set_control_override(tmp_path):
    """``--preset surrogate`` gives make control's setting; a flag given wins over it, and
    ``--set control.KEY=VALUE`` / ``--set mpc.KEY=VALUE`` over both; the scene's own --set keys pass
    through to the FEM plant. Broken once with the preset applied after the flags: --episodes 3 came
    back as 10; and a flag was taken as not given when it equalled its default."""
    from deapull.control.mpc_policy import mpc_config
    args = _parsed("--preset", "surrogate", "--out", str(tmp_path), "--episodes", "3",
                   "--set", "mpc.standoff_stds=1.5", "--set", "mpc.reach_gate=true",
                   "--set", "mpc.estimator.innovation_window=7", "--set", "mesh.n_length=4")
    assert args.policy == "mpc,sac,pd,heur" and args.plant == "surrogate:C1,surrogate:C2"
    mpc = mpc_config(args.mpc_table)
    assert args.episodes == 3 and mpc.standoff_stds == 1.5 and mpc.reach_gate is True
    assert mpc.approach_m == 1e-4 and mpc.estimator.innovation_window == 7      # the preset's, and the --set's
    assert args.mpc_model == "control/models/fa_push" and args.overrides == ["mesh.n_length=4"]
    # a flag given at its default value still wins over the preset
    assert _parsed("--preset", "surrogate", "--out", str(tmp_path), "--episodes", "10", "--noise", "0").noise == "0"
    assert mpc_config(_parsed("--preset", "surrogate", "--out", str(tmp_path)).mpc_table).standoff_stds == 2.0
    fem = _parsed("--preset", "fem", "--out", str(tmp_path))
    fem_mpc = mpc_config(fem.mpc_table)
    assert fem.plant.count("fem:") == 8 and fem_mpc.rate_V == 1.0 and fem.reach_fraction == 0.8
    assert fem.mpc_phi == "prior" and fem_mpc.estimator.innovation_window == 25


@pytest.mark.parametrize("argv, named", [
    (["--preset", "nope"], "--preset 'nope': unknown preset; shipped: fem, surrogate"),
    (["--preset", "surrogate", "--set", "control.mpc_standoff=2"], "--set control.mpc_standoff: unknown key"),
    (["--preset", "surrogate", "--set", "control.episodes=two"], "control.episodes = 'two': expected int"),
    (["--preset", "surrogate", "--set", "mpc.standof_stds=2"], "mpc.standof_stds: unknown key; allowed: horizon"),
    (["--preset", "surrogate", "--set", "mpc.inference.loss='roll'"], "choose one of step, rollout"),
    (["--preset", "surrogate", "--set", "control.mpc_phi='guess'"], "expected one of infer, prior, oracle"),
    (["--episodes", "2"], "--policy: missing"),
])
def test_a_bad_preset_or_key_exits_2_naming_it(tmp_path, capsys, argv, named):
    assert main(["control", *argv, "--out", str(tmp_path)]) == 2
    assert named in capsys.readouterr().err


def test_the_help_lists_at_most_15_options_and_options_lists_them_all(capsys):
    with pytest.raises(SystemExit):
        main(["control", "--help"])
    listed = [line for line in capsys.readouterr().out.splitlines() if line.startswith("  -")]
    assert len(listed) <= 15, listed
    assert main(["control", "--options"]) == 0
    text = capsys.readouterr().out
    assert "mpc_phi (default 'infer')" in text and "mpc.standoff_stds (default 0.0)" in text
    assert "mpc.inference.loss (default 'step')" in text and "mpc.estimator.innovation_window (default 0)" in text
