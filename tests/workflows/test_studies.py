"""The fidelity ladder and the stability study on tiny meshes and short protocols: files
written, failures as rows with PETSc's reason, resume, MPI, bad input."""
import json
import math
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
MPI = pytest.importorskip("mpi4py.MPI")

from deapull.io import cell
from deapull.workflows import fidelity, runner, stability
from deapull.workflows.runner import Case, run_cases
from tests.conftest import REPO, SHARP, mpirun

pytestmark = pytest.mark.fem

# a tiny mesh and a short protocol: 0 -> 200 V in 0.1 s, base step 0.02 s ("full": the scene's
# steps); both stages happen: the coin starts to slide at ~120 V and travels ~0.19 mm toward -x
# (27 points, a few cut-backs at the onset)
TINY = (*SHARP, "mesh.n_length=4", "mesh.n_width=1", "mesh.coin_size_m=0.004", "load.end_time_s=0.1",
        "load.ramp_time_s=0.1", "time.dt_max_s=0.02", "time.dt_initial_s=0.02", "load.voltage_max_V=200")
MOVES_MM = 0.1     # the coin travels more than this under TINY (measured 0.19 mm)
HEAD, RUNGS = fidelity.ladder()        # studies/fidelity.toml
DEFAULT, REFERENCE, SHIPPED = HEAD["default"], HEAD["reference"], HEAD["quick_default"]


def _cli(*args):
    return [sys.executable, "-m", "deapull.workflows", *args]


def _sets(overrides):
    return [a for o in overrides for a in ("--set", o)]


# --- pure functions ----------------------------------------------------------------------

def test_trajectory_errors_interpolate_onto_reference_time():
    t = np.linspace(0, 1, 11)
    ref = {"t": t, "x": -1e-3 * t, "Fy": 0.01 * t}
    run = {"t": np.linspace(0, 1, 3), "x": -1e-3 * np.linspace(0, 1, 3) - 1e-4, "Fy": 0.01 * np.linspace(0, 1, 3)}
    e = fidelity.trajectory_errors(ref, run)
    assert e["mae_x_mm"] == pytest.approx(0.1) and e["mae_Fy_mN"] == pytest.approx(0.0, abs=1e-12)
    assert e["travel_err_mm"] == pytest.approx(0.1) and e["travel_err_pct"] == pytest.approx(10.0)
    assert e["error_pct"] == pytest.approx(10.0)


def test_pareto_front_keeps_only_undominated_rungs():
    rows = [dict(case="a", status="ok", solve_s=1.0, error_pct=10.0), dict(case="b", status="ok", solve_s=2.0, error_pct=20.0),
            dict(case="c", status="ok", solve_s=3.0, error_pct=1.0),
            dict(case="ref", status="ok", solve_s=9.0, error_pct=0.0, is_reference=True),
            dict(case="f", status="failed", solve_s=0.5, error_pct=math.nan)]
    assert fidelity.pareto_front(rows) == {"a", "c"}


def test_instability_indicator_is_two_for_quadratic_growth():
    V = np.linspace(0, 400, 41)
    cols = {"V": V, "tip_ux": 0 * V, "tip_uy": -1e-3 - 1e-8 * V ** 2, "tip_uz": 0 * V}
    ind = runner.instability_indicators(cols)
    assert ind["tip_log_slope_max"] == pytest.approx(2.0) and ind["dV_collapse"] == pytest.approx(1.0)


# --- the harnesses on tiny cases -------------------------------------------------------

@pytest.fixture(scope="module")
def stability_rows(tmp_path_factory):
    out = tmp_path_factory.mktemp("stability")
    rows = stability.run_stability(out, MPI.COMM_WORLD, protocol="full", overrides=TINY,
                                   names=["baseline", "nu0.5-disp", "pullin-free-bending"])
    return out, {r["case"]: r for r in rows}


def test_stability_writes_csv_and_markdown(stability_rows):
    out, rows = stability_rows
    df = pd.read_csv(out / "stability.csv")
    assert list(df.case) == ["baseline", "nu0.5-disp", "pullin-free-bending"]
    assert list(df.ranks.fillna(0)) == [1, 0, 1]      # the ranks that solved it (a rejected scene: none)
    md = (out / "stability.md").read_text()
    assert "| baseline |" in md and "Pull-in" in md
    base = rows["baseline"]
    assert base["converged"] and base["as_expected"] and base["steps"] >= 6
    assert base["travel_mm"] > MOVES_MM            # the kinetic stage is part of the study
    for key in ("newton_iterations", "cutbacks", "min_dt_s", "max_penetration_mm", "max_force_residual_N", "wall_s"):
        assert math.isfinite(base[key]), key
    assert (out / "cases" / "baseline" / "C3.nc").exists()


def test_rejected_scene_is_a_row(stability_rows):
    row = stability_rows[1]["nu0.5-disp"]
    assert row["status"] == "rejected" and row["as_expected"]
    assert row["outcome"].startswith("rejected: ") and "poisson_ratio = 0.5" in row["outcome"]


def test_pull_in_is_detected_with_its_voltage(stability_rows):
    """Far beyond pull-in the step cannot be solved: the row says where, with PETSc's reason,
    and the tip deflection grew faster than the small-strain V^2 law before it."""
    out, rows = stability_rows
    row = rows["pullin-free-bending"]
    assert row["status"] == "failed" and row["as_expected"]
    assert row["reason"].startswith(("DIVERGED", "COUPLING", "NON_FINITE"))
    assert 0 < row["instability_V"] < 1500 and row["fail_V"] == row["instability_V"]
    assert row["tip_log_slope_max"] > 2.0 and row["dV_collapse"] > 100
    assert (out / "cases" / "pullin-free-bending" / "partial.nc").exists()


def test_diverging_case_is_a_failed_row_with_petsc_reason(tmp_path):
    case = Case("no-newton", "coin_pull", "C3", (*TINY, "solver.newton_max_it=1", "time.max_cutbacks=0"),
                "one Newton iteration, no cut-back")
    [row] = run_cases([case], tmp_path, MPI.COMM_WORLD)
    assert row["status"] == "failed" and "DIVERGED_MAX_IT" in row["reason"]
    assert math.isfinite(row["fail_t_s"]) and math.isfinite(row["fail_V"])
    assert not list((tmp_path / "cases" / "no-newton").glob("*.nc.tmp"))


def test_fidelity_ladder_writes_csv_markdown_and_pareto_plot(tmp_path):
    rows = fidelity.run_ladder("coin_pull", "C3", tmp_path, MPI.COMM_WORLD, rungs="full", overrides=TINY,
                               only=["hex-Q2-mixed-coarse", DEFAULT])
    df = pd.read_csv(tmp_path / "fidelity.csv")
    assert list(df.case) == ["hex-Q2-mixed-coarse", DEFAULT, REFERENCE]
    assert set(df.kind) == {"fem"} and set(df.status) == {"ok"}
    ref = df[df.is_reference].iloc[0]
    assert ref.mae_x_mm == 0 and ref.mae_Fy_mN == 0 and ref.dofs > df.dofs.max() / 2
    assert ref.travel_mm > MOVES_MM                 # x(t) errors compare moving coins
    default = df[df.is_default].iloc[0]
    assert default.case == DEFAULT and default.mae_Fy_mN > 0 and 0 < default.solve_s <= default.wall_s
    assert 0 < default.mae_x_mm < default.travel_mm and default.travel_mm > MOVES_MM
    assert (tmp_path / "fidelity_pareto.png").stat().st_size > 10_000
    md = (tmp_path / "fidelity.md").read_text()
    assert "Shipped default" in md and "| hex-Q2-mixed-coarse |" in md and "fidelity `as written`" in md
    assert rows[1]["newton_iterations"] > 0
    # every rung records the ranks that shared its mesh (here one), in its result and the table
    assert [json.loads(runner.result_path(tmp_path, c).read_text())["ranks"] for c in df.case] == [1, 1, 1]
    assert list(df.ranks) == [1, 1, 1] and "Ranks per rung: 1." in md
    assert set(df.fidelity) == {"as written"}      # the CSV alone says what the rungs refined
    # a reference solved on 2 ranks (as `--only <reference> --ranks-per-case 2` does), and a rung
    # stored before results had `ranks` (its dataset's `mpi_ranks` says 1): the rerun reuses both,
    # and the table names the rung whose time is not on the one-core scale
    for case, edit in ((REFERENCE, lambda r: r.update(ranks=2)), ("hex-Q2-mixed-coarse", lambda r: r.pop("ranks"))):
        path = runner.result_path(tmp_path, case)
        result = json.loads(path.read_text())
        edit(result)
        path.write_text(json.dumps(result))
    fidelity.run_ladder("coin_pull", "C3", tmp_path, MPI.COMM_WORLD, rungs="full", overrides=TINY,
                        only=["hex-Q2-mixed-coarse", DEFAULT])
    df = pd.read_csv(tmp_path / "fidelity.csv")
    assert list(df.ranks) == [1, 1, 2]
    md = (tmp_path / "fidelity.md").read_text()
    assert f"Ranks per rung: 1, except {REFERENCE} on 2: the solve time of that rung is not" in md
    assert f"`{REFERENCE}` (" in md and "dofs, 2 rank(s)" in md


def test_resume_skips_completed_case(tmp_path):
    """A case whose result exists is not solved again; a missing one (an interrupted run) is."""
    cmd = _cli("stability", "--out", str(tmp_path), "--protocol", "full", "--cases", "mu_t-0,mu_b-1", *_sets(TINY))
    first = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO)
    assert first.returncode == 0, first.stderr[-2000:]
    done = tmp_path / "cases" / "mu_t-0.json"
    stamp = done.stat().st_mtime_ns, (tmp_path / "cases" / "mu_t-0" / "C3.nc").stat().st_mtime_ns
    (tmp_path / "cases" / "mu_b-1.json").unlink()          # as if interrupted during mu_b-1
    second = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO)
    assert second.returncode == 0, second.stderr[-2000:]
    assert "1 already done, 1 to run" in second.stderr
    assert (done.stat().st_mtime_ns, (tmp_path / "cases" / "mu_t-0" / "C3.nc").stat().st_mtime_ns) == stamp
    assert json.loads((tmp_path / "cases" / "mu_b-1.json").read_text())["status"] == "ok"
    assert "mu_b-1" in second.stdout and "Traceback" not in second.stderr


@pytest.mark.mpi
def test_stability_under_mpi_spreads_cases(tmp_path):
    proc = mpirun(2, "-m", "deapull.workflows", "stability", "--out", str(tmp_path), "--protocol", "full",
                  "--cases", "baseline,mu_t-0", *_sets(TINY))
    assert proc.returncode == 0, proc.stderr[-2000:]
    df = pd.read_csv(tmp_path / "stability.csv")
    assert list(df.case) == ["baseline", "mu_t-0"] and df.converged.all()
    assert proc.stdout.count("wrote") == 1                   # rank 0 alone reports


def test_bad_input_exits_2_before_any_solve(tmp_path):
    for args in (("stability", "--cases", "nope"), ("fidelity", "--only", "nope"),
                 ("stability", "--set", "dea.poisson_ratio=2")):
        proc = subprocess.run(_cli(*args, "--out", str(tmp_path)), capture_output=True, text=True, cwd=REPO)
        assert proc.returncode == 2 and "error" in proc.stderr and "Traceback" not in proc.stderr, args
    assert not (tmp_path / "cases").exists()


@pytest.mark.mpi
def test_fewer_cases_than_rank_groups_do_not_hang(tmp_path):
    """One case on two ranks: rank 1 has nothing to solve. PETSc's initialisation is
    collective on COMM_WORLD, so it must happen on every rank before the groups split
    (it used to happen lazily on the solving rank alone, which then waited forever)."""
    proc = mpirun(2, "-m", "deapull.workflows", "stability", "--out", str(tmp_path), "--protocol", "full",
                  "--cases", "baseline", *_sets(TINY), timeout=150)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert list(pd.read_csv(tmp_path / "stability.csv").case) == ["baseline"]


def test_table_times_keep_two_digits_below_a_second():
    assert cell(39.94, "s") == "39.9"
    assert cell(0.002171, "s") == "0.0022"     # a surrogate's rollout, not "0.0"
    assert cell(float("nan"), "s") == "–"


def test_a_stored_result_is_reused_only_for_the_same_resolved_scene(tmp_path):
    """Resume skips a case whose stored result was made with the same resolved scene, and
    solves it again when the scene file (or a default) changed since — not only its name,
    setup and overrides."""
    scene_file = tmp_path / "pull.toml"
    text = (REPO / "deapull" / "scenes" / "coin_pull.toml").read_text()
    scene_file.write_text(text)
    solved = []

    def fake_solve(case, scene, out, group, progress):
        solved.append(scene.contact.slip_rate_regularisation_m_s)
        return {"status": "ok", "steps": 1}

    case = Case("c3", str(scene_file), "C3", TINY, "tiny C3")
    for _ in range(2):
        run_cases([case], tmp_path / "out", MPI.COMM_WORLD, solve=fake_solve)
    assert solved == [1e-5]                                          # the second run resumed
    scene_file.write_text(text.replace("slip_rate_regularisation_m_s = 1e-5", "slip_rate_regularisation_m_s = 1e-4"))
    [row] = run_cases([case], tmp_path / "out", MPI.COMM_WORLD, solve=fake_solve)
    assert solved == [1e-5, 1e-4] and row["status"] == "ok"           # the edited scene was solved again


def test_a_sweep_dataset_counts_as_done_only_for_its_own_scene(tmp_path):
    from deapull import dataset
    from deapull import scene as scenes
    made = scenes.load("coin_pull", setup="C3", overrides=TINY)
    other = scenes.load("coin_pull", setup="C3", overrides=(*TINY, "contact.slip_rate_regularisation_m_s=1e-4"))
    cols = {v: np.zeros(3) for v in dataset.VARIABLES}
    cols["t"] = np.arange(3.0)
    path = dataset.write(dataset.build(cols, {"scene_toml": made.to_toml()}), tmp_path / "C3.nc")
    assert dataset.is_complete(path) and dataset.is_complete(path, made.to_toml())
    assert not dataset.is_complete(path, other.to_toml())


def test_a_case_whose_output_is_gone_is_solved_again(tmp_path):
    """With ``is_done`` (the sweep: its dataset is there), a stored "ok" result alone is not
    done — a deleted dataset is solved again — while a failed row stays a row."""
    solved, outputs = [], set()

    def fake_solve(case, scene, out, group, progress):
        solved.append(case.name)
        outputs.add(case.name)
        return {"status": "failed" if case.name == "bad" else "ok", "steps": 1}

    cases = [Case(n, "coin_pull", "C3", TINY, n) for n in ("good", "bad")]
    is_done = lambda case, scene: case.name in outputs        # noqa: E731
    run_cases(cases, tmp_path, MPI.COMM_WORLD, solve=fake_solve, is_done=is_done)
    run_cases(cases, tmp_path, MPI.COMM_WORLD, solve=fake_solve, is_done=is_done)
    assert solved == ["good", "bad"]                           # resumed: nothing solved twice
    outputs.clear()                                            # the datasets were deleted
    run_cases(cases, tmp_path, MPI.COMM_WORLD, solve=fake_solve, is_done=is_done)
    assert solved == ["good", "bad", "good"]                   # the ok case again, not the failed one


def test_a_row_counts_the_fewest_contact_points_of_the_steps_that_touch():
    """``run_stats``' contact columns: the fewest contact points over the steps whose DEA
    touches the obstacle (steps before the touch, with none, do not count; NaN when it never
    touches: the free pull-in), and the table's deepest penetration in µm. A stiff penalty
    concentrates the patch onto a few points (penalty-x100 at resolved: 3), which a row must
    show. Broken once with the zeros counted: it failed (0 != 3)."""
    n = 5
    cols = {"t": np.arange(n) * 0.1, "newton_iterations": np.full(n, 3), "dt": np.full(n, 0.1),
            **{f"tip_u{k}": np.zeros(n) for k in "xyz"}, "cutbacks": np.zeros(n), "penetration_m": np.zeros(n),
            "force_balance_residual_N": np.zeros(n), "x": np.zeros(n), "wall_time_s": np.ones(n),
            "Fy": np.zeros(n), "V": np.linspace(0, 400, n), "n_contact": np.array([0, 0, 24, 3, 9]),
            "table_penetration_m": np.array([0, 1e-7, 4e-7, 3e-7, 2e-7])}
    row = runner.run_stats(cols)
    assert row["min_contact_points"] == 3
    assert row["max_table_penetration_um"] == pytest.approx(0.4)
    assert math.isnan(runner.run_stats({**cols, "n_contact": np.zeros(n)})["min_contact_points"])


GATED = """
import json, sys, time
from pathlib import Path
from mpi4py import MPI
from deapull.workflows.runner import Case, result_path, run_cases
out = Path(sys.argv[1])
names = ["gate", "a", "b", "c", "d"]

def solve(case, scene, out_dir, group, progress):
    rank = MPI.COMM_WORLD.rank
    if case.name == "gate":            # a long case: it ends once every other case is stored
        end = time.monotonic() + 20
        while not all(result_path(out_dir, n).is_file() for n in names[1:]):
            if time.monotonic() > end:
                return {{"status": "failed", "reason": "cases dealt behind the long one", "steps": 0, "rank": rank}}
            time.sleep(0.05)
    return {{"status": "ok", "steps": 1, "rank": rank}}

rows = run_cases([Case(n, "coin_pull", "C3", {tiny!r}, n) for n in names], out, MPI.COMM_WORLD, solve=solve)
if MPI.COMM_WORLD.rank == 0:
    print("ROWS" + json.dumps({{r["case"]: [r["status"], r["rank"]] for r in rows}}))
"""


def test_a_free_group_takes_the_next_case_so_a_long_case_holds_back_nothing(tmp_path):
    """Under ``mpirun -n 2`` the groups take cases as they become free: while one group is in
    a long case (here one that ends only when the other four are stored), the other group
    runs the other four. Dealt round-robin, the long case's group would hold two of them and
    wait for itself (broken once with ``todo[color::n_groups]``: the gate failed after 20 s).
    The run's claims folder is removed at the end."""
    proc = mpirun(2, "-c", GATED.format(tiny=TINY), str(tmp_path), timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    rows = json.loads(proc.stdout.split("ROWS")[1].splitlines()[0])
    assert rows["gate"][0] == "ok", rows
    others = {rows[n][1] for n in "abcd"}
    assert all(rows[n][0] == "ok" for n in "abcd") and others == {1 - rows["gate"][1]}, rows
    assert not list(tmp_path.glob(".claims-*"))


def test_a_crashed_case_is_solved_again_on_resume_a_failed_one_is_not(tmp_path):
    """A crash (``error`` row: a bug, not the case's physics) does not count as done, so a
    resumed study runs it again once the bug is fixed; a failed solve (PETSc's reason) stays
    a row. Broken once: error rows counted as done (the crashed case was not solved again)."""
    solved, crash = [], {"crash": True}

    def fake_solve(case, scene, out, group, progress):
        solved.append(case.name)
        if case.name == "crashes" and crash["crash"]:
            return {"status": "error", "reason": "TypeError: a bug", "steps": 0}
        return {"status": "failed" if case.name == "diverges" else "ok", "steps": 1}

    cases = [Case(n, "coin_pull", "C3", TINY, n) for n in ("crashes", "diverges")]
    run_cases(cases, tmp_path, MPI.COMM_WORLD, solve=fake_solve)
    crash["crash"] = False                                     # the bug is fixed
    rows = run_cases(cases, tmp_path, MPI.COMM_WORLD, solve=fake_solve)
    assert solved == ["crashes", "diverges", "crashes"]
    assert [r["status"] for r in rows] == ["ok", "failed"]


def test_stability_at_a_named_fidelity_applies_it_to_the_cases_whose_scene_defines_it():
    """``deapull stability --fidelity preview`` (no solve here): coin_pull's cases carry the
    fidelity's overrides first, so the penalty cases scale the preview's penalty; the free
    pull-in (free_bending defines none) runs as written and says so; an unknown fidelity is
    refused naming the allowed ones. Broken once: the fidelity dropped from the cases (only the
    base scene had it)."""
    from deapull import scene as scenes
    from deapull.errors import InputError
    preview = dict(o.split("=", 1) for o in scenes.fidelity_overrides("coin_pull", "preview"))
    penalty = float(preview["contact.penalty_N_m3"])
    cases = {c.name: c for c in stability.stability_cases(fidelity="preview")}
    base = cases["baseline"]
    assert all(o in base.overrides for o in scenes.fidelity_overrides("coin_pull", "preview"))
    assert f"contact.penalty_N_m3={penalty * 100.0!r}" in cases["penalty-x100"].overrides
    free = cases["pullin-free-bending"]
    assert not any(o.startswith("mesh.tip_zone") for o in free.overrides)
    assert "as written" in free.description and "as written" not in base.description
    plain = {c.name: c for c in stability.stability_cases()}
    assert not any(o.startswith("contact.quadrature_degree=8") for o in plain["baseline"].overrides)
    with pytest.raises(InputError, match="fidelity = 'finest'.*allowed: preview"):
        stability.stability_cases(fidelity="finest")


def test_the_ladder_at_a_named_fidelity_refines_that_fidelity_in_every_rung():
    """``deapull fidelity --fidelity preview`` (no solve here): every rung is the preview scene
    changed in its own knobs, so the reference is its mesh at level + 1 and the coarse rung halves
    its 8 elements along the length; the user's --set still wins; an unknown fidelity is refused
    naming the allowed ones. Broken once: with the fidelity not applied in ladder_cases, the rungs
    were the file's and this failed."""
    from deapull import scene as scenes
    from deapull.errors import InputError
    preview = scenes.load("coin_pull", setup="C3", overrides=scenes.fidelity_overrides("coin_pull", "preview"))
    cases = {c.name: c for c in fidelity.ladder_cases("coin_pull", "C3", "quick", ("coin.mu_b=0.3",),
                                                      fidelity="preview")}
    assert len(cases) == len(RUNGS)

    def scene(name):
        return scenes.load("coin_pull", setup="C3", overrides=cases[name].overrides)
    ref, coarse, shipped = scene(REFERENCE), scene("hex-Q2-mixed-coarse"), scene(SHIPPED)
    assert ref.mesh.level == preview.mesh.level + 1 and ref.mesh.tip_zone_m == preview.mesh.tip_zone_m
    assert ref.contact.penalty_N_m3 == preview.contact.penalty_N_m3 and ref.time.dt_max_s == 0.005
    assert coarse.mesh.n_length == preview.mesh.n_length // 2 == 4
    assert shipped.time.dt_max_s == preview.time.dt_max_s and shipped.coin.mu_b == 0.3
    assert shipped.contact.quadrature_degree == 8 == preview.contact.quadrature_degree
    with pytest.raises(InputError, match="fidelity = 'finest'.*allowed: preview"):
        fidelity.ladder_cases("coin_pull", "C3", fidelity="finest")


def test_a_new_run_removes_the_claims_of_a_killed_run(tmp_path):
    """A run killed with -9 leaves its ``.claims-<run>/`` behind; the next run on this host removes
    the folders whose owner has stopped and keeps a running one's. Broken once with the removal
    skipped: the dead run's folder stayed."""
    import os
    import subprocess
    import sys
    from mpi4py import MPI
    from deapull.workflows.runner import Claims
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    host = __import__("socket").gethostname()
    for name, pid in (("killed", dead.pid), ("running", os.getpid())):
        folder = tmp_path / f".claims-{name}"
        (folder / "C1").mkdir(parents=True)
        (folder / Claims.OWNER).write_text(f"{host} {pid}\n")
    claims = Claims(tmp_path, MPI.COMM_SELF)
    left = sorted(p.name for p in tmp_path.glob(".claims-*"))
    assert ".claims-killed" not in left and ".claims-running" in left and claims.folder.name in left
    assert (claims.folder / Claims.OWNER).read_text().split() == [host, str(os.getpid())]
    claims.remove()
