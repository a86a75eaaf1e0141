"""The stepping API: run() reproduces the records of the code before it, advance() takes a
voltage chosen at run time, a failing step is cut into sub-steps that land on t + dt and
V_end, a step that cannot be solved rolls back; the independent force balance."""
import math
import tomllib

import numpy as np
import pytest
import xarray as xr

from deapull import dataset, scene as scenes
from deapull.fem_solver.coin import CoinState, force_balance_residual
from deapull.fem_solver.simulation import Simulation
from deapull.fem_solver.stepping import SolveFailed
from tests.fem_solver.conftest import C3_TEST, balance_bound_N, c3_reference

#: float columns of the paper's table, compared to round-off
TABLE = ("t", "x", "u", "V", "dt", "Fx", "Fy")
INTEGER = ("newton_iterations", "coupling_iterations", "cutbacks", "stick")
#: changed on purpose: wall time, and the force balance is now the independent one
NOT_COMPARED = ("wall_time_s", "force_balance_residual_N")
#: relative to the column's largest value, or to the largest of its group's (SCALE_GROUPS). Measured:
#: 0 (bit-identical) with the BLAS the fixture was written with (the reference BLAS); with OpenBLAS
#: (make setup, since 2026-11-27) the LU's round-off moves u by 3e-11 and Fx by 3e-12 of their
#: largest values, the integers not at all
ROUND_OFF = 1e-9
#: columns that are zero up to round-off get their group's scale: tip_uz in the half model (~6e-18 m)
#: the tip's, and the net volume change (~1e-10, incompressible) that of |J - 1|
SCALE_GROUPS = (("tip_ux", "tip_uy", "tip_uz"), ("volume_change", "mean_abs_J_minus_1"))
#: scene keys and variables added after the fixture was written (issue 12); C3_TEST pins the keys
#: to the behaviour the fixture had
ADDED_KEYS = {"contact": ("quadrature_degree", "quadrature_rule", "min_active_points", "reach_m"), "mesh": ("symmetry", "x_grading", "tip_zone_m", "tip_zone_divisions", "rim_band_m", "rim_band_divisions"),
              "solver": ("linear_solver", "line_search_reuse_ratio", "predictor"), "time": ("placement_first_step",)}
ADDED_VARIABLES = ("penetration_qp_m", "n_contact", "contact_x", "contact_z", "contact_abs_z", "table_Rx",
                   "table_Ry", "table_penetration_m", "patch_vx", "patch_normal_x", *dataset.PATCH_DRAGS)
#: sections added since (issue 23), pinned out of reach in C3_TEST
ADDED_SECTIONS = ("table",)
#: keys renamed since, with the value the fixture's run had under the old name
RENAMED_KEYS = {("contact", "penalty_N_m3"): ("penalty_scale", 10.0)}


def test_run_reproduces_the_records_before_the_stepping_api(c3_run):
    """C3 at test size through run() = advance() loop, against the dataset the code before
    the API wrote (tests/data/sweep/C3.nc): every variable but the two changed on purpose."""
    sc, path = c3_run
    new, old = xr.open_dataset(path), xr.open_dataset(c3_reference())
    same_scene = [tomllib.loads(d.attrs["scene_toml"]) for d in (new, old)]
    for section, keys in ADDED_KEYS.items():                             # keys added since, at the old behaviour
        for key in keys:
            same_scene[0][section].pop(key)
    for section in ADDED_SECTIONS:
        same_scene[0].pop(section)
    for (section, key), (old_key, old_value) in RENAMED_KEYS.items():
        same_scene[0][section].pop(key)
        same_scene[0][section][old_key] = old_value
    assert same_scene[0] == same_scene[1]                                # the same resolved scene
    assert new.sizes == old.sizes
    assert set(new.data_vars) - set(ADDED_VARIABLES) == set(old.data_vars)
    for name in old.data_vars:
        if name in NOT_COMPARED:
            continue
        a, b = new[name].values, old[name].values
        if name in INTEGER:
            np.testing.assert_array_equal(a, b, err_msg=name)
        else:
            columns = next((g for g in SCALE_GROUPS if name in g), (name,))
            scale = max(max(float(np.abs(old[c].values).max()) for c in columns), 1e-300)
            assert float(np.abs(a - b).max()) <= ROUND_OFF * scale, name
    assert set(TABLE) <= set(old.data_vars)


def test_independent_force_balance_is_at_the_newton_tolerance(c3_run):
    """The coin's momentum balance with the DEA's force from the clamp reaction: zero up to
    the Newton residual (bound: (1 + μ_b) √n atol, conftest.balance_bound_N). Measured on
    this run: largest 1.25e-8 N, median over the slip steps 3.9e-9 N, i.e. ≈ 5e-6 μ_b m g;
    the bound is 3.4e-7 N."""
    sc, path = c3_run
    ds = xr.open_dataset(path)
    res = ds.force_balance_residual_N.values
    bound = balance_bound_N(sc, ds.attrs["mesh_dofs"])
    weight_friction = sc.coin.mu_b * ds.attrs["coin_mass_kg"] * sc.gravity_m_s2
    slip = ds.stick.values == 0
    assert slip.sum() > 100                            # the balance is tested while the coin slides
    assert float(res.max()) <= bound < 1e-3 * weight_friction
    # of the Newton residual's size, not round-off: the old check, zero by construction, gave 1e-18 N
    assert float(np.median(res[slip])) > 1e-3 * bound


def _stepper(tmp_path, *overrides, setup="C3", scene="coin_pull"):
    sc = scenes.load(scene, setup=setup, overrides=(*C3_TEST, *overrides))
    return Simulation.from_scene(sc, mesh_dir=tmp_path / "mesh").stepper(progress=False)


def test_a_broken_coupling_shows_in_the_balance_but_not_in_the_old_check(tmp_path, monkeypatch):
    """Hand the coin 90 % of the DEA's push (both the coupling and the record see the wrong
    Fx): the old residual, which re-evaluated the Coulomb update with the Fx the stepper
    used, stays at round-off (measured 1.7e-18 N); the independent one reports the lost
    10 % of Fx (5.0–5.7e-4 N)."""
    stepper = _stepper(tmp_path, "load.end_time_s=0.45")
    p = stepper.p
    right = p.obstacle_forces
    monkeypatch.setattr(p, "obstacle_forces", lambda: (0.9 * right()[0], right()[1]))
    records = stepper.run()
    sc, mass = stepper.scene, stepper.mass_kg
    slip = [r for r in records if not r.stick]
    assert len(slip) > 20
    old = [force_balance_residual(CoinState(a.x, a.u, bool(a.stick)), CoinState(b.x, b.u, bool(b.stick)),
                                  b.Fx, b.Fy, b.dt, mass, sc.coin.mu_b, sc.gravity_m_s2)
           for a, b in zip(records, records[1:])]
    assert max(old) < 1e-15
    new = np.array([r.force_balance_residual_N for r in slip])
    lost = np.array([abs(r.Fx) / 0.9 * 0.1 for r in slip])       # the 10 % the coin did not get
    assert np.all(new == pytest.approx(lost, rel=1e-3))
    assert new.min() > 1e3 * balance_bound_N(sc, p.num_dofs())


def test_advance_takes_a_voltage_chosen_at_run_time(tmp_path):
    """A controller's loop, V chosen from the last record: ramp 4 V per ms until the coin has
    slid 20 µm toward -x, hold that voltage 30 ms, ramp down to 0 in 20 ms. Every record is
    at the asked time and voltage (steps that needed cut-backs included: the first, 4 V with
    friction just switched on, and the sudden hold); on hold friction stops the coin and
    keeps it; going down, the retracting tip pulls toward +x and presses less."""
    stepper = _stepper(tmp_path)
    rec = stepper.start()
    assert (rec.t, rec.V, rec.x) == (0.0, 0.0, 0.0)
    dt, V, t = 1e-3, 0.0, 0.0
    phases = {"up": [], "hold": [], "down": []}
    while not phases["up"] or (phases["up"][-1].x > -2e-5 and V < 300):
        V += 4.0
        phases["up"].append(stepper.advance(V, dt))
    V_hold = V
    assert V_hold < 300 and phases["up"][-1].x <= -2e-5           # the coin slid toward -x
    for _ in range(30):
        phases["hold"].append(stepper.advance(V_hold, dt))
    for k in range(1, 21):
        phases["down"].append(stepper.advance(V_hold * (1 - k / 20), dt))
    records = [r for phase in phases.values() for r in phase]
    assert stepper.records[1:] == records
    for r in records:                                        # the time and voltage the caller asked for
        t += dt
        assert r.t == t and r.dt == dt
    assert [r.V for r in phases["hold"]] == [V_hold] * 30 and phases["down"][-1].V == 0.0
    hold = phases["hold"]
    assert hold[-1].stick == 1 and hold[-1].u == 0.0         # friction stops the coin under a held voltage
    rest = [r.x for r in hold if r.stick]
    assert len(rest) > 20 and max(rest) == min(rest)
    down = phases["down"]
    assert hold[-1].Fx < 0 < down[-1].Fx                     # the push reverses as the tip retracts
    assert down[-1].Fy < 0.5 * hold[-1].Fy
    for r in records:
        assert r.force_balance_residual_N <= balance_bound_N(stepper.scene, stepper.p.num_dofs())


class Injected:
    """Wraps Stepper._attempt (one try of a (sub-)step: the full-Newton-step solve and its
    retry with a line search): attempts whose index is in ``fail`` diverge (leaving a
    scribbled state behind, as a real divergence does); every attempt's (V, dt) is logged."""

    def __init__(self, stepper, fail):
        self.stepper, self.attempt, self.fail = stepper, stepper._attempt, fail
        self.calls, self.its = [], []

    def __call__(self, V, dt, ratio, tip_before):
        index = len(self.calls)
        self.calls.append((V, dt))
        if index in self.fail or (self.fail == "all"):
            p = self.stepper.p
            p.w.x.array[:] += 1e-3
            p.set_load(V, 1.0, dt)
            return False, "DIVERGED_INJECTED", 7, 1, None, None
        out = self.attempt(V, dt, ratio, tip_before)
        self.its.append(out[2:4])
        return out


def test_a_failed_step_is_cut_into_substeps_that_land_on_its_end(tmp_path, monkeypatch):
    """Fail the full step and then the second half: the step is retaken as dt/2, then the
    remaining half as two dt/4 sub-steps, V linear in between; the record is at t + dt and
    V_end, counts 2 cut-backs and sums the sub-steps' iterations; the result agrees with an
    unbroken step of the same size."""
    steppers = [_stepper(tmp_path / "a"), _stepper(tmp_path / "b")]
    for s in steppers:
        s.start()
        for k in range(1, 6):
            s.advance(8.0 * k, 2e-3)
    broken, plain = steppers
    t0, V0, dt, V_end = broken.t, broken.V, 2e-3, 56.0
    spy = Injected(broken, fail={0, 2})
    monkeypatch.setattr(broken, "_attempt", spy)
    rec = broken.advance(V_end, dt)
    dV = V_end - V0
    expected = [(V_end, dt), (V0 + dV / 2, dt / 2), (V_end, dt / 2), (V0 + 3 * dV / 4, dt / 4), (V_end, dt / 4)]
    assert [c[0] for c in spy.calls] == pytest.approx([e[0] for e in expected], rel=1e-15)
    assert [c[1] for c in spy.calls] == pytest.approx([e[1] for e in expected], rel=1e-12)
    assert rec.t == t0 + dt and rec.V == V_end and rec.dt == dt       # exactly on the step's end
    assert rec.cutbacks == 2 and broken.substep_dt == pytest.approx(dt / 4, rel=1e-12)
    assert rec.newton_iterations == sum(i for i, _ in spy.its)
    assert rec.coupling_iterations == sum(c for _, c in spy.its)
    ref = plain.advance(V_end, dt)
    assert rec.Fy == pytest.approx(ref.Fy, rel=1e-3) and rec.tip_uy == pytest.approx(ref.tip_uy, rel=1e-3)
    assert rec.force_balance_residual_N <= balance_bound_N(broken.scene, broken.p.num_dofs())


def test_a_step_that_cannot_be_solved_rolls_back(tmp_path, monkeypatch):
    """The first dt/2 sub-step succeeds, everything after it fails: after time.max_cutbacks
    cut-backs in a row SolveFailed names the failed attempt's end time and voltage and PETSc's reason, nothing
    is recorded, and the stepper is back at its last record — the next step equals that of a
    stepper that never failed."""
    steppers = [_stepper(tmp_path / "a"), _stepper(tmp_path / "b")]
    for s in steppers:
        s.start()
        for k in range(1, 4):
            s.advance(10.0 * k, 2e-3)
    broken, plain = steppers
    n, t0, V0, coin0 = len(broken.records), broken.t, broken.V, broken.coin
    spy = Injected(broken, fail=set(range(2, 100)) | {0})
    monkeypatch.setattr(broken, "_attempt", spy)
    with pytest.raises(SolveFailed, match="DIVERGED_INJECTED") as info:
        broken.advance(60.0, 2e-3)
    cuts = broken.scene.time.max_cutbacks
    # the full step, one good sub-step, then max_cutbacks + 1 failures in a row from there
    assert len(spy.calls) == 1 + 1 + cuts + 1
    V_fail, h_fail = spy.calls[-1]
    assert h_fail == pytest.approx(2e-3 / 2 ** (cuts + 1), rel=1e-12)
    assert info.value.t == pytest.approx(t0 + 1e-3 + h_fail, rel=1e-12)
    assert info.value.voltage == V_fail and info.value.reason == "DIVERGED_INJECTED"
    assert info.value.last_good_step == n - 1 and len(broken.records) == n
    [sub] = info.value.substeps                          # the rolled-back sub-step, for diagnosis
    assert (sub.t, sub.V, sub.dt) == pytest.approx((t0 + 1e-3, (V0 + 60.0) / 2, 1e-3), rel=1e-12)
    assert (broken.t, broken.V, broken.coin) == (t0, V0, coin0)
    for name in ("w", "w_old", "w_older"):                 # the same history, so the same arrays
        np.testing.assert_array_equal(getattr(broken.p, name).x.array, getattr(plain.p, name).x.array, name)
    assert float(broken.p.X_old.value) == float(plain.p.X_old.value) == float(broken.p.X.value)
    monkeypatch.undo()
    a, b = broken.advance(40.0, 2e-3), plain.advance(40.0, 2e-3)
    assert (a.t, a.V, a.x, a.u, a.stick) == (b.t, b.V, b.x, b.u, b.stick)
    # the Newton path differs (the reused Jacobian and the coupling's secant saw the good
    # sub-step), so the forces agree to the Newton tolerance (measured 4e-8 relative)
    for name in ("Fx", "Fy", "tip_uy"):
        assert getattr(a, name) == pytest.approx(getattr(b, name), rel=1e-6), name


def test_run_follows_a_protocol_callable(tmp_path):
    """run(protocol) steps a voltage protocol other than the scene's: each record's V is
    protocol(t) (here up and down on the free beam, no coin)."""
    stepper = _stepper(tmp_path, "gravity_m_s2=0", "dea.width_m=0.004", "mesh.n_length=4",
                       "time.dt_initial_s=0.01", "time.dt_max_s=0.01", scene="free_bending", setup=None)

    def protocol(t):
        return 40.0 * (1 - abs(1 - t / 0.03))            # 0 -> 40 V at 30 ms -> 0 at 60 ms

    records = stepper.run(protocol, end_time_s=0.06)
    assert len(records) == 7 and records[-1].t == pytest.approx(0.06, rel=1e-12)
    assert [r.V for r in records] == [protocol(r.t) for r in records]
    tip = [r.tip_uy for r in records]
    assert tip[3] < tip[2] < 0 and abs(tip[-1]) < 1e-3 * abs(tip[3])     # bends and comes back
    with pytest.raises(RuntimeError, match="already"):
        stepper.start()
    with pytest.raises(ValueError):
        stepper.advance(0.0, -1e-3)
    with pytest.raises(ValueError):
        stepper.advance(math.nan, 1e-3)


def test_a_triangle_turns_at_its_peak_without_cut_backs(tmp_path):
    """C3 at test size, 0 -> 400 V in 0.25 s and back down to 200 V at 0.375 s. At the peak the
    tip's friction on the coin reverses: full Newton steps cycled there (|F| alternating for 40
    iterations at every step size), the stepper cut back 9 times and crawled on at a fraction of
    the step, and on the shipped mesh (C1, 0.5 s ramps) a later tiny step converged on another
    branch (tip +26 mm / -32 mm, contact lost, the coin later pushed to -6.2 mm). Now the step
    after the peak is retried with a line search: no cut-back, full steps, the free end moves
    continuously, contact holds, and the coin stops and is pulled back toward the clamp."""
    stepper = _stepper(tmp_path, "load.protocol='triangle'", "load.ramp_time_s=0.25", "load.end_time_s=0.375")
    records = stepper.run()
    t = np.array([r.t for r in records])
    x = np.array([r.x for r in records])
    tip = np.array([(r.tip_ux, r.tip_uy) for r in records])
    peak = int(np.flatnonzero(np.isclose(t, 0.25, rtol=0, atol=1e-12))[0])
    assert records[peak].V == 400.0 and x[peak] < -5e-4           # the coin slid toward -x on the way up
    assert sum(r.cutbacks for r in records) == 0                   # was 9, all at the reversal
    dt_max = stepper.scene.time.dt_max_s
    assert all(r.dt == pytest.approx(dt_max, rel=1e-9) for r in records[peak + 1:-1])
    assert float(np.abs(np.diff(tip, axis=0)).max()) < 1e-4       # legitimate steps move it <= 2.2e-5 m
    Fy = np.array([r.Fy for r in records])
    assert Fy[peak:].min() > 0.2 * Fy[peak]                        # the tip stays on the coin (Fy(200 V) ~ 0.3 Fy(400 V))
    assert float(np.abs(np.diff(Fy)).max()) < 0.02 * Fy[peak]      # and presses continuously
    after = x[peak:]
    # the coin, sliding at u toward -x, stops within a few steps (kinetic friction and the
    # reversed tip friction both brake it) and does not go further than sliding to rest
    # under ground friction alone would take it
    g, mu_b = stepper.scene.gravity_m_s2, stepper.scene.coin.mu_b
    assert after.min() >= x[peak] - records[peak].u ** 2 / (2 * mu_b * g) - 1e-9
    assert x[-1] > after.min() + 1e-5                              # then pulled back toward the clamp


def test_a_line_search_that_runs_out_of_iterations_gets_a_longer_try_not_a_cut_back(tmp_path):
    """The triangle above with Newton capped at 10 iterations: around the peak the line search
    needs more, and a cut-back does not lower that (the reversal is as sharp at every step
    size). The longer try (3 × the cap, ``LONG_NEWTON_FACTOR``) takes every step whole: no
    cut-back, 20 s. Broken once (factor 1, so the last try is the failed one repeated): 139
    cut-backs and 88 s. At resolved v2 the C5 triangle's peak failed the same way at the
    shipped cap of 40 (84 iterations needed) and the case was lost. The gate is the peak's quarter
    of the triangle (0.2–0.29 s): later, where the coin slides back, a step may need one cut-back on
    some CPUs (measured: t = 0.2986 s, 110 iterations, on an AMD EPYC), which the production path
    avoids by the friction continuation, off here."""
    stepper = _stepper(tmp_path, "load.protocol='triangle'", "load.ramp_time_s=0.25", "load.end_time_s=0.375",
                       "solver.newton_max_it=10")
    stepper.FRICTION_CONTINUATION = False      # the longer try alone (the continuation has its own test)
    records = stepper.run()
    peak = [r for r in records if 0.2 <= r.t <= 0.29]
    assert sum(r.cutbacks for r in peak) == 0
    assert max(r.newton_iterations for r in peak) > 10             # some step needed the longer try
    assert records[-1].t == pytest.approx(0.375)


def test_a_fast_push_onset_converges_by_continuation_in_the_friction_regularisation(tmp_path, monkeypatch):
    """The MPC's full push (0 -> 400 V in 80 ms at 1 ms steps) at the scene's ε_v = 1e-5 m/s: where the
    tip starts to slip fast the line search fails, and the step is solved at 100, 10 and 1 × ε_v in turn,
    each from the last; no cut-back. Broken once (no continuation): 3 cut-backs on this mesh (at the
    data fidelity the push's onset steps each took a 120-iteration try instead and the push sweep
    crawled)."""
    stepper = _stepper(tmp_path, "load.ramp_time_s=0.08", "load.end_time_s=0.12", "time.dt_max_s=0.001",
                       "contact.slip_rate_regularisation_m_s=1e-5")
    calls = []
    solve = stepper._friction_continuation
    monkeypatch.setattr(stepper, "_friction_continuation", lambda *a: calls.append(a) or solve(*a))
    records = stepper.run()
    assert calls                                                   # some step needed it
    assert sum(r.cutbacks for r in records) == 0
    assert stepper.p.slip_reg.value == pytest.approx(1e-5)         # the scene's ε_v after it
    assert records[-1].t == pytest.approx(0.12) and records[-1].x < -5e-4


def test_a_step_that_jumps_branch_is_not_recorded(tmp_path, monkeypatch):
    """A converged solve whose free end moved 5 mm in one step (Newton landed on another
    equilibrium, as at the C1 triangle's peak) is refused and the step taken again; the record
    equals that of a stepper that never jumped."""
    steppers = [_stepper(tmp_path / "a"), _stepper(tmp_path / "b")]
    for s in steppers:
        s.start()
        for k in range(1, 4):
            s.advance(10.0 * k, 2e-3)
    jumped, plain = steppers
    solve = jumped._coupled_solve
    calls = []

    def jump_once(V, dt, *rest):
        out = solve(V, dt, *rest)
        calls.append(jumped.line_search)
        if len(calls) == 1:
            jumped.p.w.x.array[:] += 5e-3                 # every displacement (and pressure) dof
        return out

    monkeypatch.setattr(jumped, "_coupled_solve", jump_once)
    rec, ref = jumped.advance(40.0, 2e-3), plain.advance(40.0, 2e-3)
    assert len(calls) >= 2                               # refused, then solved again
    # the same state up to the Newton tolerance (the retry may take sub-steps; the jump was 5 mm)
    assert abs(rec.tip_uy - ref.tip_uy) < 1e-7 and abs(rec.tip_ux - ref.tip_ux) < 1e-7
    tol = jumped.scene.solver.coupling_tol_m
    assert (rec.t, rec.V) == (ref.t, ref.V) and rec.x == pytest.approx(ref.x, abs=tol)


def test_placement_lands_on_the_same_equilibrium_whatever_its_first_step(tmp_path):
    """The gravity continuation's first step (``time.placement_first_step``) changes the path,
    not the placed state: the full-gravity first try and a first quarter reach the same tip
    displacement and the same forces to the Newton tolerance."""
    placed = {}
    for first in (1.0, 0.25, 0.1):
        stepper = _stepper(tmp_path / str(first), f"time.placement_first_step={first}")
        rec = stepper.start()
        placed[first] = (stepper.p.tip_displacement().copy(), rec.Fy, rec.newton_iterations)
    tip, Fy, its = placed[1.0]
    assert len({p[2] for p in placed.values()}) > 1                    # the paths differ
    for first in (0.25, 0.1):
        # to the Newton tolerance: atol 1e-8 N over the tip's ~200 N/m is 5e-11 m (measured:
        # 4.4e-12 m with the placement's 12-iteration cap, below 4e-12 m without it)
        assert np.abs(placed[first][0] - tip).max() <= 1e-8 * np.abs(tip).max(), first
        # forces to the Newton residual's absolute tolerance (N; measured: 1.2e-9 N of 4 mN)
        assert abs(placed[first][1] - Fy) <= stepper.scene.solver.newton_atol, first


def test_a_stiff_penalty_is_placed_by_continuation_onto_the_same_equilibrium(tmp_path, monkeypatch):
    """A coin penalty above ``PLACEMENT_PENALTY_N_M3`` is placed at that penalty, then raised
    to the scene's: the placed state is the one a direct placement at the stiff penalty
    reaches (to the Newton tolerance), the penalty ends at the scene's value and Newton's cap
    is the scene's again. Broken once: the raise skipped (the penalty stayed at the
    placement's: the penalty assert, and without it the tip 2.9e-7 m off)."""
    from deapull.fem_solver import stepping
    k = "contact.penalty_N_m3=1.12e11"              # x 100 the fixture's
    direct = _stepper(tmp_path / "direct", k)
    monkeypatch.setattr(stepping, "PLACEMENT_PENALTY_N_M3", math.inf)
    ref = direct.start()
    monkeypatch.setattr(stepping, "PLACEMENT_PENALTY_N_M3", 1.12e9)
    stepper = _stepper(tmp_path / "raised", k)
    rec = stepper.start()
    p = stepper.p
    assert float(p.penalty.value) == 1.12e11
    assert p.snes.getTolerances()[3] == stepper.scene.solver.newton_max_it
    tip, tip_ref = p.tip_displacement(), direct.p.tip_displacement()
    assert np.abs(tip - tip_ref).max() <= 1e-9 * np.abs(tip_ref).max()
    # the force is k_n times a depth converged to the Newton tolerance: at this k_n the two
    # placements' Fy differ by 1.2e-8 N of 4 mN (measured)
    assert abs(rec.Fy - ref.Fy) <= 1e-5 * abs(ref.Fy)


def test_the_coins_acceleration_in_the_first_guess_saves_coupling_solves_and_moves_nothing(c3_run, tmp_path):
    """The test-size C3 with the coupling's first guess extrapolating the sliding coin's velocity
    by its last acceleration (the default) against the same run without it (c3_run): fewer DEA
    solves in the coupling, the same trajectory to the coupling's tolerance. Measured here: 1222 ->
    925 coupling iterations, x within 2.3e-10 m (the preview C3: 1273 -> 1071, Newton 4831 -> 4252).
    Broken once with the acceleration's sign flipped: 1246 coupling iterations, more than without."""
    from deapull.fem_solver.run import solve_scene
    sc, without = c3_run
    with_ = solve_scene(sc, tmp_path, progress=False)
    a, b = xr.open_dataset(with_), xr.open_dataset(without)
    assert int(a.coupling_iterations.sum()) < int(b.coupling_iterations.sum())
    assert float(np.abs(a.x.values - b.x.values).max()) <= 20 * sc.solver.coupling_tol_m


def test_a_looser_coupling_tolerance_saves_solves_and_moves_the_coin_by_about_it(tmp_path):
    """The test-size C3 with the coin-DEA iteration converged to 1 nm (coin_pull's
    ``solver.coupling_tol_m``, a path key) against 0.1 nm: fewer coupling iterations and Newton
    iterations, the same records, x within a few tolerances. Measured here: 923 -> 743 coupling
    iterations, Newton 2217 -> 1940, x within 9.9e-10 m of a 0.69 mm travel (the data fidelity's C3:
    Newton 4,447 -> 3,771, x(0.95 s) 2e-6 of itself). Broken once (the test against 0.1 nm whatever
    the key): equal counts."""
    from deapull.fem_solver.run import solve_scene
    runs = {}
    for tol in (1e-10, 1e-9):
        sc = scenes.load("coin_pull", setup="C3", overrides=(*C3_TEST, f"solver.coupling_tol_m={tol}"))
        runs[tol] = xr.open_dataset(solve_scene(sc, tmp_path / f"{tol:g}", progress=False))
    tight, loose = runs[1e-10], runs[1e-9]
    assert int(loose.coupling_iterations.sum()) < 0.9 * int(tight.coupling_iterations.sum())
    assert int(loose.newton_iterations.sum()) < int(tight.newton_iterations.sum())
    assert tight.sizes == loose.sizes and float(np.abs(tight.x.values - loose.x.values).max()) <= 5e-9


def test_the_quadratic_predictor_saves_newton_iterations_and_moves_nothing(tmp_path):
    """The test-size C3 with the DEA's state extrapolated through the last three accepted states (the
    default) against the linear predictor: fewer Newton iterations, the same trajectory to the
    coupling's tolerance. Measured here: 3769 -> 2217 iterations, x within 2.8e-10 m (the data
    fidelity: 5,781 -> 4,447). Broken once (the quadratic weights of twice the step): more
    iterations than the linear predictor."""
    from deapull.fem_solver.run import solve_scene
    runs = {}
    for predictor in ("linear", "quadratic"):
        sc = scenes.load("coin_pull", setup="C3", overrides=(*C3_TEST, f"solver.predictor='{predictor}'"))
        runs[predictor == "quadratic"] = xr.open_dataset(solve_scene(sc, tmp_path / predictor, progress=False))
    a, b = runs[True], runs[False]
    assert int(a.newton_iterations.sum()) < 0.8 * int(b.newton_iterations.sum())
    assert a.sizes == b.sizes and float(np.abs(a.x.values - b.x.values).max()) <= 20 * sc.solver.coupling_tol_m


def test_a_cycling_newton_solve_is_ended_as_stalled_and_a_slowly_converging_one_is_not(tmp_path):
    """The residuals of C3's full Newton steps at the onset of sliding (data fidelity, t = 0.3125 s:
    after one good iteration they cycle between four values for all 40 iterations, each with a fresh
    Jacobian, 15 s of the run) end the solve STALL_ITERATIONS after the smallest one, as diverged and
    ``stalled``; a damped solve that cuts its residual by 5 % per iteration is left to converge.
    Broken once (the stall test removed): the cycle ran to its 40th iteration."""
    from petsc4py import PETSc
    from deapull.fem_solver import problem
    p = _stepper(tmp_path, "gravity_m_s2=0", "dea.width_m=0.004", "mesh.n_length=4", scene="free_bending",
                 setup=None).p
    R = PETSc.SNES.ConvergedReason
    cycle = [5.226e-4, 1.968e-4] + [1.891e-3, 9.356e-4, 1.430e-3, 1.978e-3] * 10
    reasons = [p._converged(p.snes, it, (0.0, 0.0, f)) for it, f in enumerate(cycle)]
    stop = next(i for i, r in enumerate(reasons) if r != R.ITERATING)
    assert stop == 1 + problem.STALL_ITERATIONS and reasons[stop] == R.DIVERGED_MAX_IT and p.stalled
    slow = [1e-3 * 0.95 ** k for k in range(41)]
    reasons = [p._converged(p.snes, it, (0.0, 0.0, f)) for it, f in enumerate(slow)]
    assert all(r == R.ITERATING for r in reasons[:-1]) and not p.stalled
    assert reasons[-1] == R.DIVERGED_MAX_IT          # the scene's cap of 40 iterations still holds
    assert p._converged(p.snes, 1, (0.0, 0.0, 1e-12)) == R.CONVERGED_FNORM_ABS


@pytest.mark.parametrize("full_newton", [True, False])
def test_the_placement_assembles_a_jacobian_at_every_iteration_and_has_no_stall_test(tmp_path, monkeypatch,
                                                                                   full_newton):
    """With solver.jacobian_reuse_ratio = 0.6 the placement's penalty continuation failed on the data
    fidelity when it kept the Jacobian: the placement runs with a fresh one at every iteration and
    without the stall test (the cycle of the test above is not ended inside it). The same placement
    with Stepper.PLACEMENT_FULL_NEWTON off keeps Jacobians, which shows that the count can fail."""
    from petsc4py import PETSc
    from deapull.fem_solver.stepping import Stepper
    monkeypatch.setattr(Stepper, "PLACEMENT_FULL_NEWTON", full_newton)
    stepper = _stepper(tmp_path, "solver.jacobian_reuse_ratio=0.6", "time.placement_first_step=0.25")
    stepper.start()
    p = stepper.p
    if full_newton:
        assert p.jacobian_reuses == 0 and p.jacobian_assemblies > 0
        with p.placement_newton():
            cycle = [5.226e-4, 1.968e-4] + [1.891e-3, 9.356e-4, 1.430e-3, 1.978e-3] * 3
            reasons = [p._converged(p.snes, it, (0.0, 0.0, f)) for it, f in enumerate(cycle)]
        assert all(r == PETSc.SNES.ConvergedReason.ITERATING for r in reasons)
    else:
        assert p.jacobian_reuses > 0
    assert not p._placing                         # the block restores the scene's Newton


def test_a_line_search_keeps_its_jacobian_longer_and_lands_on_the_same_path(tmp_path):
    """The triangle above, whose peak needs the line search (which then stays on), at
    ``solver.line_search_reuse_ratio`` 0.95 (the default) against 0.6 (the full-step solves' ratio, as
    it was): the damped iterations keep the factorised Jacobian, so fewer are assembled, and the
    path is the same to the solver's tolerances. Measured here: 216 -> 175 assemblies, x(t) within
    6e-11 m (the step control counts Newton iterations, so the steps may differ). Broken once (the
    line search's solves taking solver.jacobian_reuse_ratio): equal counts."""
    runs = {}
    for ratio in (0.6, 0.95):
        stepper = _stepper(tmp_path / str(ratio), "load.protocol='triangle'", "load.ramp_time_s=0.25",
                           "load.end_time_s=0.375", f"solver.line_search_reuse_ratio={ratio}")
        records = stepper.run()
        assert stepper.line_search != "basic"                      # the peak switched it on
        runs[ratio] = stepper.p.jacobian_assemblies, np.array([(r.t, r.x) for r in records])
    (slow, x_slow), (kept, x_kept) = runs[0.6], runs[0.95]
    assert kept < 0.9 * slow
    # the step control counts Newton iterations, so the steps may differ: x(t) compared between them
    assert float(np.abs(np.interp(x_slow[:, 0], *x_kept.T) - x_slow[:, 1]).max()) < 1e-8


def test_the_clamp_reaction_read_off_the_solve_is_a_fresh_assembly_and_never_stale(tmp_path):
    """After a converged solve the clamp reaction comes from the solve's last residual (no
    assembly): it equals a fresh assembly of F at that state; once the load has moved (a new
    voltage, nothing solved since) the kept sums are not used. Broken once with the constants
    left out of the fingerprint: the second check returned the pre-load reaction."""
    stepper = _stepper(tmp_path, "load.end_time_s=0.05")
    stepper.start()
    stepper.advance(20.0, 1 / 720)
    p = stepper.p

    def fresh():
        kept, p._last_reaction = p._last_reaction, None
        try:
            return p.clamp_reaction()
        finally:
            p._last_reaction = kept

    p.set_load(40.0, float(p.X.value), 1 / 720)
    assert p.solve().converged
    assert p.clamp_reaction() == pytest.approx(fresh(), rel=1e-12, abs=1e-15)
    before = p.clamp_reaction()
    p.set_load(120.0, float(p.X.value), 1 / 720)           # the Maxwell stress changes, the unknowns do not
    now = p.clamp_reaction()
    assert now == pytest.approx(fresh(), rel=1e-12, abs=1e-15)
    assert abs(now[0] - before[0]) + abs(now[1] - before[1]) > 1e-9


def _placed(tmp_path, name, setup, cache, *overrides):
    sc = scenes.load("coin_pull", setup=setup, overrides=(*C3_TEST, *overrides))
    sim = Simulation.from_scene(sc, mesh_dir=tmp_path / name)
    stepper = sim.stepper(progress=False, placement_cache=cache)
    rec = stepper.start()
    return stepper, rec, sim


def test_the_setups_share_one_placement_and_a_cached_state_is_only_a_first_guess(tmp_path):
    """C1..C8 differ in the coin's density and friction, which the frictionless placement with the
    coin at rest does not see. C6 placed from C3's cached state is ``reused`` in fewer Newton
    iterations and lands where C6 placed alone does (to the Newton tolerance). A cached state that is
    not the placement (here C3's scaled by 1.5) is only the last solve's first guess: the placement
    still lands there. Another penalty is another key. Broken once: the reused state kept without
    its solve (the scaled state's tip 50 % off)."""
    from deapull.fem_solver.simulation import PlacementCache
    cache = tmp_path / "placements"
    c3, c3_rec, c3_sim = _placed(tmp_path, "C3", "C3", cache)
    alone, alone_rec, _ = _placed(tmp_path, "alone", "C6", None)
    reused, reused_rec, c6_sim = _placed(tmp_path, "C6", "C6", cache)
    assert (c3.placement, alone.placement, reused.placement) == ("solved", "solved", "reused")
    assert reused_rec.newton_iterations < alone_rec.newton_iterations
    tip = alone.p.tip_displacement()
    atol = alone.scene.solver.newton_atol
    assert np.abs(reused.p.tip_displacement() - tip).max() <= 1e-8 * np.abs(tip).max()
    assert abs(reused_rec.Fy - alone_rec.Fy) <= atol

    (stored,) = cache.glob("placement-*.npy")
    np.save(stored, 1.5 * np.load(stored))
    foreign, foreign_rec, _ = _placed(tmp_path, "foreign", "C6", cache)
    assert np.abs(foreign.p.tip_displacement() - tip).max() <= 1e-8 * np.abs(tip).max()
    assert abs(foreign_rec.Fy - alone_rec.Fy) <= atol

    key = PlacementCache(cache, c3_sim.scene, c3_sim.mesh_path, c3_sim.comm).key
    assert PlacementCache(cache, c6_sim.scene, c6_sim.mesh_path, c6_sim.comm).key == key
    stiffer = scenes.load("coin_pull", setup="C3", overrides=(*C3_TEST, "contact.penalty_N_m3=2.24e9"))
    assert PlacementCache(cache, stiffer, c3_sim.mesh_path, c3_sim.comm).key != key
