"""Time stepping of one scene, with the coin coupled in every step.

(Longer than ~500 lines on purpose: placement, the coupled solve, cut-backs and the run loop
share the one Stepper's state; split, each part would reach into the others.)

The caller owns the voltage and the step size::

    stepper = Stepper(problem, mass_kg)      # or Simulation.from_scene(...).stepper()
    stepper.start()                      # placement under gravity at t = 0, the first record
    rec = stepper.advance(V_end, dt)     # one step t -> t + dt, V linear up to V_end
    ...

and :meth:`Stepper.run` is the loop over :meth:`Stepper.advance` for a protocol V(t)
(the scene's ramp by default), with adaptive step control.

Each step: predict the state by linear extrapolation, then iterate DEA solve ↔ coin
update (staggered, secant-accelerated on the coin position) until the coin position
changes by less than ``solver.coupling_tol_m``. The coupling is staggered rather than
monolithic because the coin is one scalar unknown with a non-smooth (stick/slip) law:
dolfinx 0.5 has no global real unknowns. The coin position X maps to X ↦ x_n + Δt u(X)
with slope −Δt² k / m (k the DEA tip's tangential stiffness, m the coin's mass), below 1 at
the shipped steps, so even the plain fixed point contracts; the secant on G(X) = x(X) − X
converges in a few warm-started solves (the figures: docs/physics.md, "The coin and the
coupling").

Each (sub-)step starts from the predictor (linear extrapolation by the ratio of the step to
the last one; none where the voltage turns) with full Newton steps; a solve that fails, or
converges on another branch (the DEA's free end moved more than
:data:`MAX_TIP_MOVE_PER_STEP` of its thickness in one step), is tried once more with a
backtracking line search, which then stays on for the run. Why: where the tip's
rate-regularised friction reverses (a triangle's peak, a random input's turn), full Newton
steps cycle (the friction flips within a slip of ε_v Δt), cut-backs only sharpen that, and
can end on another equilibrium branch (docs/physics.md, "The coin and the coupling", for the
case measured). With the line search that step converges at full size; ramps never need it
and are unchanged to the bit.

A step that still fails is restored and retried as ``1 / time.cutback`` (rounded up) equal
sub-steps, the voltage interpolated linearly between the step's start and end values, so
the step still ends at t + Δt and V_end; a failing sub-step is cut again. After more than
``time.max_cutbacks`` cut-backs in a row from one accepted state, or below
``time.dt_min_s``, the state is rolled back to the last record and :class:`SolveFailed`
raised with the time, the voltage and PETSc's reason — nothing is recorded from a failed
solve.

Every accepted (sub-)step also checks the coin's momentum balance with the DEA's force
taken from the clamp reaction, not from the contact integral the coupling used
(``force_balance_residual_N``; :meth:`DEAProblem.obstacle_forces_from_reaction`).
"""
from __future__ import annotations

import contextlib
import logging
import math
import time as _time
from dataclasses import asdict, dataclass
from typing import Callable

import numpy as np
from tqdm import tqdm

from deapull import dataset, protocol as protocols
from deapull.protocol import Protocol
from deapull.fem_solver.coin import CoinState, coulomb_step, force_balance_residual

log = logging.getLogger(__name__)


class SolveFailed(RuntimeError):
    """The solve could not continue; carries where and why.

    ``records`` are the accepted steps (the stepper is back at the last of them);
    ``substeps`` the sub-steps that the failed step had accepted before it gave up, rolled
    back since, each as a record of its own (t, V, dt of the sub-step) — for diagnosis,
    e.g. how far the cut-backs crawled toward a limit point.
    """

    def __init__(self, t: float, voltage: float, reason: str, last_good_step: int, records, substeps=()):
        self.t, self.voltage, self.reason, self.last_good_step = t, voltage, reason, last_good_step
        self.records, self.substeps = records, list(substeps)
        super().__init__(f"solve failed at t = {t:.6g} s (V = {voltage:.4g} V): {reason}; "
                         f"last good step {last_good_step}")


@dataclass
class StepRecord:
    t: float
    x: float
    u: float
    V: float
    dt: float
    Fx: float
    Fy: float
    newton_iterations: int
    coupling_iterations: int
    cutbacks: int
    penetration_m: float
    penetration_qp_m: float
    stick: int
    force_balance_residual_N: float
    tip_ux: float
    tip_uy: float
    tip_uz: float
    mean_abs_J_minus_1: float
    volume_change: float
    n_contact: int
    contact_x: float
    contact_z: float
    contact_abs_z: float
    table_Rx: float
    table_Ry: float
    table_penetration_m: float
    patch_vx: float
    patch_normal_x: float
    patch_drag_000: float
    patch_drag_050: float
    patch_drag_075: float
    patch_drag_090: float
    patch_drag_095: float
    patch_drag_100: float
    wall_time_s: float


PLACEMENT_MIN_STEP = 1e-3  # smallest gravity-continuation step of the initial placement
#: a stiffer coin penalty than this is reached at placement by continuation from it (geometric in
#: k_n, after gravity): the DEA first touches the coin part-way through the gravity continuation, and
#: full Newton steps cross that touch-down at a soft penalty, in about a third of the iterations
#: (tests/fem_solver/test_stepping.py::test_a_stiff_penalty_is_placed_by_continuation_onto_the_same_equilibrium)
PLACEMENT_PENALTY_N_M3 = 2.24e7
#: Newton's cap in a continuation step of the placement: a cut step is cheaper than a long
#: failing solve
PLACEMENT_MAX_IT = 12
#: largest move of the DEA's free-end face in one (sub-)step, as a fraction of the DEA's thickness;
#: a converged solve that moves it further jumped to another equilibrium branch and is cut back
#: (legitimate steps move it by a small fraction of h, the branch jumps it rejects by many h: docs/physics.md)
MAX_TIP_MOVE_PER_STEP = 0.25
#: SNES line search of the second try of a (sub-)step whose full-Newton-step solve failed
LINE_SEARCH_RETRY = "bt"
#: the last try of a (sub-)step whose line-search solve ran out of iterations: the line search
#: again with this many times ``solver.newton_max_it``: at a reversal the line search converges slowly
#: at every step size, so more iterations help where a cut-back does not
#: (tests/fem_solver/test_stepping.py::test_a_line_search_that_runs_out_of_iterations_gets_a_longer_try_not_a_cut_back)
LONG_NEWTON_FACTOR = 3
#: the friction regularisation's factors, in turn, of a (sub-)step solved by continuation after its
#: line-search try failed (:meth:`Stepper._friction_continuation`); the last is the scene's own
FRICTION_CONTINUATION = (100.0, 10.0, 1.0)


def scene_protocol(scene) -> Protocol:
    """The scene's voltage protocol (:mod:`deapull.protocol`): a callable V(t) with its kinks."""
    return protocols.from_load(scene.load)


class Stepper:
    """Steps one scene's problem and collects one record per accepted step.

    Parameters
    ----------
    problem : fem_solver.problem.DEAProblem
    mass_kg : mass of the coin (None when the scene has no coin)
    progress : show a progress bar in :meth:`run` (rank 0 only)
    on_step : called as ``on_step(index, t)`` after each accepted step, before its record is kept

    Attributes
    ----------
    t, V : time and voltage of the last record
    coin : the coin's state at the last record
    records : the records so far
    substep_dt : size of the last accepted (sub-)step; below the step's size after a cut-back
    """

    #: extrapolate the sliding coin's velocity by its last acceleration in the coupling's first guess
    #: (tests/fem_solver/test_stepping.py counts the coupling solves it saves)
    PREDICT_ACCELERATION = True
    #: place the DEA with :meth:`DEAProblem.placement_newton` (a fresh Jacobian at every iteration, no
    #: stall test): with the Jacobian kept at solver.jacobian_reuse_ratio = 0.6 the penalty continuation
    #: failed (tests/fem_solver/test_stepping.py checks a placement at that ratio)
    PLACEMENT_FULL_NEWTON = True
    #: try a failed line-search solve once more by continuation in the friction's regularisation
    #: (:meth:`_friction_continuation`) before the long try and the cut-backs
    FRICTION_CONTINUATION = True

    def __init__(self, problem, mass_kg=None, progress: bool = True, on_step=None, placement_cache=None):
        self.p, self.scene = problem, problem.scene
        self.placement_cache = placement_cache    # a simulation.PlacementCache, or None
        self.placement = "solved"                 # or "reused": how start() placed the DEA
        self.mass_kg = mass_kg
        self.coin = CoinState()
        self.records: list[StepRecord] = []
        self.on_step = on_step
        self.progress = progress and problem.comm.rank == 0
        self.coupling_slope = -1.0  # dG/dX of the coin-position fixed point, refined by secants
        self.coin_accel = 0.0       # the sliding coin's acceleration over the last accepted (sub-)step
        self.t, self.V = 0.0, math.nan
        self.substep_dt: float | None = None   # also the predictor's last interval
        self.substep_dV = 0.0                  # voltage change over that interval (predictor direction)
        self.prev_dt: float | None = None      # the interval before it (None: w_{n-2} not on this path)
        self.prev_dV = 0.0
        self.started = False
        self.steps_below_min_points = 0        # records whose contact had fewer points than the scene asks
        self.tip_move_max_m = MAX_TIP_MOVE_PER_STEP * (problem.scene.dea.active_thickness_m
                                                       + problem.scene.dea.passive_thickness_m)

    # --- one coupled solve ------------------------------------------------------------

    def _coupled_solve(self, V: float, dt: float, X0: float | None = None):
        """DEA ↔ coin iteration for one step from the coin position ``X0`` (default: the coin's
        predictor); returns (ok, reason, newton its, coupling its, coin, forces)."""
        p, sc = self.p, self.scene
        if sc.coin is None:
            p.set_load(V, 0.0, dt)
            res = p.solve()
            forces = p.obstacle_forces() if res.converged else None
            return res.converged, res.reason, res.iterations, 1, self.coin, forces
        g, mu_b, tol = sc.gravity_m_s2, sc.coin.mu_b, sc.solver.coupling_tol_m
        # the coin's backward-Euler position with its velocity extrapolated by the last acceleration
        # (a sliding coin speeds up with the ramp: without it the first guess lags and the secant
        # needs one more DEA solve per step)
        X = self.coin.x + dt * (self.coin.u + dt * self.coin_accel) if X0 is None else X0
        hist = []
        its = 0
        for k in range(1, sc.solver.coupling_max_it + 1):
            p.set_load(V, X, dt)
            res = p.solve()
            its += res.iterations
            if not res.converged:
                return False, res.reason, its, k, None, None
            Fx, Fy = p.obstacle_forces()
            new = coulomb_step(self.coin, Fx, Fy, dt, self.mass_kg, mu_b, g)
            G = new.x - X
            if abs(G) <= tol:
                return True, res.reason, its, k, CoinState(X, new.u, new.stick), (Fx, Fy)
            hist.append((X, G))
            if len(hist) >= 2 and hist[-1][1] != hist[-2][1]:
                (x0, g0), (x1, g1) = hist[-2], hist[-1]
                self.coupling_slope = min(max((g1 - g0) / (x1 - x0), -1e3), -0.1)
            X = X - G / self.coupling_slope
        return False, "COUPLING_NOT_CONVERGED", its, sc.solver.coupling_max_it, None, None

    def _balance_residual(self, prev: CoinState, new: CoinState, dt: float) -> float:
        """The coin's momentum balance with the DEA's force from the clamp reaction (N).

        Independent of the contact integral that the coupling handed to the coin: it is the
        force the quasi-static DEA actually exerts (minus its other external forces), so it
        checks the DEA's equilibrium and the coupling's hand-over together. Must be called
        before ``problem.accept()`` (the friction term needs the step's start state).
        """
        sc = self.scene
        if sc.coin is None:
            return 0.0
        Fx, Fy = self.p.obstacle_forces_from_reaction()
        return force_balance_residual(prev, new, Fx, Fy, dt, self.mass_kg, sc.coin.mu_b, sc.gravity_m_s2)

    def _info(self, *args) -> None:
        """log.info on rank 0 of the solve's communicator (one mesh split over ranks logs once)."""
        if self.p.comm.rank == 0:
            log.info(*args)

    def _record(self, t, V, dt, its, coupling_its, cutbacks, wall, forces, residual) -> StepRecord:
        """The record of the state just solved (forces from the solve, before accept())."""
        p = self.p
        p.check_reach()        # raises if the underside touches the obstacle outside the contact integral
        Fx, Fy = forces
        tip = p.tip_displacement()
        n_contact, penetration_qp = p.contact_point_stats()
        mean_abs_J_minus_1, volume_change = p.volume_changes()
        cx, cz, cabs = p.contact_centre() if n_contact else (0.0, 0.0, 0.0)
        Rx, Ry = p.table_reaction()
        shares = dataset.PATCH_SHARES      # the first record (placement, dt = 0) has no step to probe
        vx, normal_x, drags = p.patch_probe(shares) if dt > 0 else (0.0, 0.0, [0.0] * len(shares))
        rec = StepRecord(t=t, x=self.coin.x, u=self.coin.u, V=V, dt=dt, Fx=Fx, Fy=Fy, newton_iterations=its,
                         coupling_iterations=coupling_its, cutbacks=cutbacks, penetration_m=p.max_penetration(),
                         penetration_qp_m=penetration_qp,
                         stick=int(self.coin.stick), force_balance_residual_N=residual, tip_ux=tip[0],
                         tip_uy=tip[1], tip_uz=tip[2], mean_abs_J_minus_1=mean_abs_J_minus_1,
                         volume_change=volume_change, n_contact=n_contact,
                         contact_x=cx if math.isfinite(cx) else 0.0, contact_z=cz if math.isfinite(cz) else 0.0,
                         contact_abs_z=cabs if math.isfinite(cabs) else 0.0,
                         table_Rx=Rx, table_Ry=Ry, table_penetration_m=p.table_penetration(),
                         patch_vx=vx, patch_normal_x=normal_x,
                         **dict(zip(dataset.PATCH_DRAGS, drags)), wall_time_s=wall)
        values = np.array([v for v in asdict(rec).values()], dtype=float)
        if not np.all(np.isfinite(values)):
            return None
        return rec

    def _keep(self, rec: StepRecord) -> StepRecord:
        need = self.scene.contact.min_active_points
        if self.scene.has_obstacle and 0 < rec.n_contact < need:
            if not self.steps_below_min_points and self.p.comm.rank == 0:
                log.warning("t = %.4g s: only %d contact point(s) carry the DEA-obstacle contact "
                            "(contact.min_active_points = %d): the contact patch is not resolved, and the "
                            "forces depend on the mesh and the rule (docs/fem_accuracy.md)",
                            rec.t, rec.n_contact, need)
            self.steps_below_min_points += 1
        if self.on_step is not None:
            self.on_step(len(self.records), rec.t)
        self.records.append(rec)
        self.t, self.V = rec.t, rec.V
        return rec

    # --- the API ------------------------------------------------------------------------

    def start(self, V0: float | None = None) -> StepRecord:
        """Equilibrium at t = 0 under gravity and ``V0`` (default: the scene's protocol at 0);
        the first record.

        The DEA is placed on the obstacle without friction: friction acts on slip during a
        step, and placement is not a step of the protocol. Gravity is applied by
        continuation; a continuation step below :data:`PLACEMENT_MIN_STEP` raises
        :class:`SolveFailed`. With a :attr:`placement_cache` that holds this mesh's placement
        (another setup's: it does not depend on the coin's density or friction), one solve from
        it replaces the continuation (:attr:`placement` says which).
        """
        if self.started:
            raise RuntimeError("Stepper.start() was already called")
        start = _time.perf_counter()
        V = scene_protocol(self.scene)(0.0) if V0 is None else float(V0)
        self.p.enable_friction(False)
        dt = self.scene.time.dt_initial_s
        reused = self._reuse_placement(V, dt)
        its, cits, forces = reused if reused is not None else self._place(V, dt)
        if reused is None and self.placement_cache is not None:
            self.placement_cache.save(V, self.p.w.x.array)
        self.placement = "solved" if reused is None else "reused"
        self.coin = CoinState()
        residual = self._balance_residual(self.coin, self.coin, 0.0)   # as solved: without friction
        self.p.enable_friction(True)
        rec = self._record(0.0, V, 0.0, its, cits, 0, _time.perf_counter() - start, forces, residual)
        if rec is None:
            raise SolveFailed(0.0, V, "NON_FINITE_OUTPUT", -1, self.records)
        self.p.accept()
        self.p.accept()  # no history yet: the predictor starts from a constant state
        self.started = True
        return self._keep(rec)

    def _reuse_placement(self, V: float, dt: float):
        """The placement from :attr:`placement_cache`: its state as the first guess of the placement's
        last solve (full gravity and penalty, at ``V``), kept when that solve converges; returns
        (Newton iterations, coupling iterations, forces), or None (no cache, no state, or the solve
        failed: the problem is then back at rest)."""
        cached = None if self.placement_cache is None else self.placement_cache.load(V, self.p.w.x.array.size)
        if cached is None:
            return None
        rest = self.p.w.x.array.copy()
        self.p.w.x.array[:] = cached
        self.p.gravity_scale.value = 1.0
        with self._placement_newton():
            ok, reason, its, cits, _, forces = self._coupled_solve(V, dt)
        if ok:
            self._info("placement reused from %s (%d Newton iterations)", self.placement_cache.folder, its)
            return its, cits, forces
        self._info("the cached placement did not solve (%s); placing from rest", reason)
        self.p.w.x.array[:] = rest
        return None

    def _place(self, V: float, dt: float):
        """The DEA placed from rest by continuation: gravity at a soft penalty, the penalty raised,
        then the initial voltage; returns (Newton iterations, coupling iterations, forces)."""

        def gravity(scale):
            self.p.gravity_scale.value = scale
            return self._coupled_solve(0.0 if V > 0 else V, dt)

        penalty = self.p.penalty   # the coin's normal penalty, a Constant (None: no obstacle)
        k_target = float(penalty.value) if penalty is not None else 0.0
        k_place = min(k_target, PLACEMENT_PENALTY_N_M3)
        if penalty is not None:
            penalty.value = k_place
        its, cits, forces = self._continuation("placement under gravity", gravity, V)
        if k_place < k_target:   # a stiff penalty: raised geometrically from the settled soft contact

            def stiffen(scale):
                penalty.value = k_place * (k_target / k_place) ** scale
                return self._coupled_solve(0.0 if V > 0 else V, dt)

            k_its, cits, forces = self._continuation("placement, penalty raised", stiffen, V)
            its += k_its
            penalty.value = k_target
        if V > 0:   # a protocol that starts actuated (release): then raise the voltage, still frictionless
            k_its, cits, forces = self._continuation("placement at the initial voltage",
                                                     lambda scale: self._coupled_solve(scale * V, dt), V)
            its += k_its
        return its, cits, forces

    def advance(self, V_end: float, dt: float) -> StepRecord:
        """One step from the current time t to t + dt, the voltage going linearly to ``V_end``.

        The coupled DEA–coin solve; when it fails, the state is restored and the rest of the
        step is taken as equal sub-steps ``time.cutback`` times shorter (V interpolated
        linearly), cut again on each failure; the record's iteration counts are summed over
        the accepted sub-steps, ``cutbacks`` counts every cut, ``force_balance_residual_N``
        is the largest of the sub-steps'.

        Raises
        ------
        SolveFailed
            after more than ``time.max_cutbacks`` cut-backs in a row from one accepted state
            (as the loop before the API allowed per step), or below ``time.dt_min_s``, with
            the end time and voltage of the failed attempt; the state is rolled back to the
            last record and nothing is recorded (the sub-steps it had accepted are on the
            exception, ``substeps``).
        """
        if not self.started:
            raise RuntimeError("call Stepper.start() before Stepper.advance()")
        V_end, dt = float(V_end), float(dt)
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"time step must be a positive number, got {dt!r}")
        if not math.isfinite(V_end):
            raise ValueError(f"voltage must be finite, got {V_end!r}")
        ts = self.scene.time
        wall0 = _time.perf_counter()
        t0, V0, coin0, dt_prev0, dV_prev0 = self.t, self.V, self.coin, self.substep_dt, self.substep_dV
        tip0 = self.p.tip_displacement()
        saved = None                          # the accepted arrays, copied at the first cut-back
        substeps = []                         # records of the accepted sub-steps, for a SolveFailed
        its = cits = cutbacks = fails = 0     # cut-backs: in the step; fails: in a row at one point
        residual = 0.0
        elapsed, h, n_left = 0.0, dt, 1      # time done, sub-step size, sub-steps left
        while True:
            last = n_left == 1
            step = dt - elapsed if last and elapsed > 0 else h
            t_end = t0 + dt if last else t0 + elapsed + step
            V = V_end if last else V0 + (V_end - V0) * ((elapsed + step) / dt)
            V_start = V0 + (V_end - V0) * (elapsed / dt)
            ok, reason, k_its, k_cits, coin, forces = self._attempt(V, step, self._predictor_weights(step, V - V_start),
                                                                    tip0)
            if not ok:
                self.p.restore()
                if saved is None:
                    saved = self._save()
                cutbacks, fails = cutbacks + 1, fails + 1
                self._info("t = %.6g s, dt = %.3g s: %s after %d Newton iterations; cutting back",
                           t_end - step, step, reason, k_its)
                h = step * ts.cutback
                if fails > ts.max_cutbacks or h < ts.dt_min_s:
                    self._rollback(saved, coin0, dt_prev0, dV_prev0)
                    raise SolveFailed(t_end, V, reason, len(self.records) - 1, self.records, substeps)
                remaining = dt - elapsed
                n_left = max(1, math.ceil(remaining / h * (1 - 1e-12)))
                h = remaining / n_left
                continue
            its, cits, fails = its + k_its, cits + k_cits, 0
            prev, self.coin = self.coin, coin
            sliding = not (coin.stick or prev.stick) and self.PREDICT_ACCELERATION
            self.coin_accel = (coin.u - prev.u) / step if sliding else 0.0
            balance = self._balance_residual(prev, coin, step)
            residual = max(residual, balance)
            self.prev_dt, self.prev_dV = self.substep_dt, self.substep_dV
            self.substep_dt, self.substep_dV = step, V - V_start
            if last:
                break
            sub = self._record(t_end, V, step, k_its, k_cits, cutbacks, _time.perf_counter() - wall0, forces, balance)
            substeps += [sub] if sub is not None else []
            self.p.accept()
            tip0 = self.p.tip_displacement()
            elapsed += step
            n_left -= 1
        rec = self._record(t0 + dt, V_end, dt, its, cits, cutbacks, _time.perf_counter() - wall0, forces,
                           residual)
        if rec is None:
            self._rollback(saved, coin0, dt_prev0, dV_prev0)
            raise SolveFailed(t0 + dt, V_end, "NON_FINITE_OUTPUT", len(self.records) - 1, self.records)
        self.p.accept()
        return self._keep(rec)

    def _attempt(self, V: float, step: float, weights: tuple, tip_before):
        """One (sub-)step from the predictor: the coupled solve with full Newton steps and, if
        that fails (or jumps branch, :meth:`_continuous`), once more from the same predictor
        with a backtracking line search; returns what :meth:`_coupled_solve` returns, the
        iterations summed over both tries.

        Full Newton steps cycle where the rate-regularised friction reverses over the contact
        (its tangential force flips within a slip of ε_v Δt): at a triangle's peak |F| alternates
        between two values at every step size, so cutting back only sharpens the flip. The line
        search (``snes_linesearch_type bt``) converges that step at full size
        (tests/fem_solver/test_stepping.py::test_a_triangle_turns_at_its_peak_without_cut_backs).
        Steps that converge with full steps (every step of the ramps) never see it. Once the
        line search has saved a step it stays on for the rest of the run (the first try of
        every later step uses it: a turning load turns again, and a failed full-step try
        costs up to ``solver.newton_max_it`` iterations). A step whose retry fails too goes
        back to full Newton steps for its cut-backs; once the line search is on, a failed
        try is cut back with it.

        A line-search try that runs out of iterations (DIVERGED_MAX_IT) gets one more, from
        the same predictor, with :data:`LONG_NEWTON_FACTOR` × ``solver.newton_max_it``
        iterations before the step is cut back: at a reversal the line search can converge
        slowly at every step size, so a cut-back does not help, while more iterations do.
        """
        def attempt(first: bool):
            if not first:
                self.p.restore()
            self.p.predict(weights)
            ok, reason, k_its, k_cits, coin, forces = self._coupled_solve(V, step)
            if ok:
                ok, reason = self._continuous(tip_before, reason)
            return ok, reason, k_its, k_cits, coin, forces

        ok, reason, its, cits, coin, forces = attempt(first=True)
        if ok:
            return ok, reason, its, cits, coin, forces
        switched = self.line_search != LINE_SEARCH_RETRY
        if switched:
            self._info("t = %.6g s, dt = %.3g s: %s with full Newton steps; retrying with a line search",
                       self.t, step, reason)
            self.p.set_line_search(LINE_SEARCH_RETRY)
            ok, reason, k_its, k_cits, coin, forces = attempt(first=False)
            its, cits = its + k_its, cits + k_cits
        if not ok and self.FRICTION_CONTINUATION and (self.scene.has_obstacle or self.scene.table is not None):
            self._info("t = %.6g s, dt = %.3g s: %s with the line search; by continuation in the friction's "
                       "regularisation (x %s)", self.t, step, reason, ", ".join(f"{k:g}" for k in FRICTION_CONTINUATION))
            ok_c, reason_c, k_its, k_cits, coin, forces = self._friction_continuation(V, step, weights, tip_before)
            its, cits = its + k_its, cits + k_cits
            if ok_c:
                ok, reason = ok_c, reason_c
        if not ok and reason == "DIVERGED_MAX_IT":
            long_it = LONG_NEWTON_FACTOR * self.scene.solver.newton_max_it
            self._info("t = %.6g s, dt = %.3g s: %s with the line search; once more with %d iterations",
                       self.t, step, reason, long_it)
            with self.p.newton_max_it(long_it):
                ok, reason, k_its, k_cits, coin, forces = attempt(first=False)
            its, cits = its + k_its, cits + k_cits
        if not ok and switched:
            self.p.set_line_search("basic")
        return ok, reason, its, cits, coin, forces

    def _friction_continuation(self, V: float, step: float, weights: tuple, tip_before):
        """The (sub-)step from the predictor solved at the friction regularisation ε_v times each of
        :data:`FRICTION_CONTINUATION` in turn, each solve starting from the last; what
        :meth:`_coupled_solve` returns at the scene's ε_v, the iterations summed.

        Newton converges on the rate-regularised friction only within a slip of about ε_v Δt of the
        answer. Where the tip starts to slip fast (the push's onset at 5 V per 1 ms step) the line
        search runs out of its iterations; from the solution at a larger ε_v, whose basin is as much
        wider, Newton converges at the next (docs/physics.md; tests/fem_solver/test_stepping.py::
        test_a_fast_push_onset_converges_by_continuation_in_the_friction_regularisation).
        """
        self.p.restore()
        self.p.predict(weights)
        its = cits = 0
        coin = None
        for scale in FRICTION_CONTINUATION:
            with self.p.friction_regularisation(scale):      # each from the last stage's DEA and coin
                ok, reason, k_its, k_cits, coin, forces = self._coupled_solve(V, step, None if coin is None else coin.x)
            its, cits = its + k_its, cits + k_cits
            if not ok:
                self._info("t = %.6g s, dt = %.3g s: %s at %g x the friction's regularisation after %d Newton "
                           "iterations", self.t, step, reason, scale, k_its)
                return ok, reason, its, cits, coin, forces
        ok, reason = self._continuous(tip_before, reason)
        return ok, reason, its, cits, coin, forces

    @property
    def line_search(self) -> str:
        """The line search of the Newton solve under way (``basic``, or LINE_SEARCH_RETRY on a retry)."""
        return self.p.line_search

    def _predictor_ratio(self, step: float, dV: float) -> float:
        """Extrapolation factor of the predictor for a (sub-)step of ``step`` s over which the
        voltage changes by ``dV``: the ratio of the step to the last one, except where the
        voltage turns (``dV`` against the last step's change: a triangle's peak, a random
        input's turn, a controller reversing), where the state is *not* extrapolated (0).

        Extrapolating across a turn pushes the DEA further the way it was going while the
        load now pulls it back, and after a short kink-landing step by several times that
        step: the solve then needs
        cut-backs, whose tiny sub-steps make the rate-regularised friction a near-jump in the
        displacement (its width is ε_v Δt) — see :data:`MAX_TIP_MOVE_PER_STEP`.
        """
        if self.substep_dt is None:
            return 0.0
        if dV * self.substep_dV < 0.0:
            return 0.0
        return step / self.substep_dt

    def _predictor_weights(self, step: float, dV: float) -> tuple[float, ...]:
        """Weights of the predictor (:meth:`DEAProblem.predict`) for a (sub-)step of ``step`` s over
        which the voltage changes by ``dV``: the quadratic Lagrange extrapolation through the last
        three accepted states where the voltage moved the same way over this step and both last
        intervals (``solver.predictor = "quadratic"``), else linear by :meth:`_predictor_ratio`.

        Quadratic where the coin slides: the DEA's state curves with the ramp, and the linear guess
        leaves a first residual ≈ 1e-4, ten times the stuck coin's. C3 at the data fidelity: Newton
        iterations 5,624 -> 4,447 together with ``solver.line_search_reuse_ratio`` (which alone moved
        them 5,625 -> 5,781), the travel equal to 1e-7 (bench/reference/fem_speed.json).
        """
        if (self.scene.solver.predictor == "quadratic" and self.prev_dt is not None and self.substep_dt is not None
                and dV * self.substep_dV > 0.0 and self.substep_dV * self.prev_dV > 0.0):
            h1, h0, s = self.substep_dt, self.prev_dt, step
            return ((s + h1) * (s + h1 + h0) / (h1 * (h1 + h0)), -s * (s + h1 + h0) / (h1 * h0),
                    s * (s + h1) / ((h1 + h0) * h0))
        r = self._predictor_ratio(step, dV)
        return 1.0 + r, -r

    def _continuous(self, tip_before, reason: str) -> tuple[bool, str]:
        """Refuse a converged solve whose free end moved more than ``tip_move_max_m`` in one
        (sub-)step: Newton left the branch (e.g. it overshot through the coin and converged on
        the free-curling DEA, contact lost), which a quasi-static path never does. The step is
        then cut back like a diverged one; if the jump persists the step fails (SolveFailed)
        instead of recording a wrong branch."""
        move = float(np.linalg.norm(self.p.tip_displacement() - tip_before))
        if move > self.tip_move_max_m:
            return False, f"BRANCH_JUMP (free end moved {move * 1e3:.3g} mm in one step)"
        return True, reason

    @contextlib.contextmanager
    def _placement_newton(self):
        """Newton as the placement runs it: :meth:`DEAProblem.placement_newton` (with
        :attr:`PLACEMENT_FULL_NEWTON`) and at most :data:`PLACEMENT_MAX_IT` iterations."""
        newton = self.p.placement_newton() if self.PLACEMENT_FULL_NEWTON else contextlib.nullcontext()
        with self.p.newton_max_it(min(PLACEMENT_MAX_IT, self.scene.solver.newton_max_it)), newton:
            yield

    def _continuation(self, what: str, solve_at, V: float):
        """Solve ``solve_at(scale)`` for scale 0 → 1 in growing steps (the first
        ``time.placement_first_step``), cut by 4 on failure, with :meth:`DEAProblem.placement_newton`.

        Returns (Newton iterations, coupling iterations of the last solve, its forces);
        raises :class:`SolveFailed` once a step falls below :data:`PLACEMENT_MIN_STEP`.
        """
        its, done, step = 0, 0.0, self.scene.time.placement_first_step
        good = self.p.w.x.array.copy()
        while done < 1.0:
            scale = min(1.0, done + step)
            with self._placement_newton():
                ok, reason, k_its, cits, coin, forces = solve_at(scale)
            its += k_its
            if ok:
                done, step, good[:] = scale, step * 1.5, self.p.w.x.array
                continue
            self.p.w.x.array[:] = good
            step /= 4
            self._info("%s x %.4g: %s; continuation step cut to %.3g", what, scale, reason, step)
            if step < PLACEMENT_MIN_STEP:
                raise SolveFailed(0.0, V, f"{what} x {scale:g}: {reason}", -1, self.records)
        return its, cits, forces

    def _save(self):
        """Copies of the last accepted state's arrays (before any sub-step is accepted)."""
        p = self.p
        return p.w_old.x.array.copy(), p.w_older.x.array.copy(), float(p.X_old.value)

    def _rollback(self, saved, coin: CoinState, dt_prev, dV_prev=0.0) -> None:
        """Back to the state of the last record."""
        p = self.p
        if saved is not None:
            p.w_old.x.array[:], p.w_older.x.array[:] = saved[0], saved[1]
            p.X_old.value = saved[2]
        p.restore()
        self.coin, self.substep_dt, self.substep_dV = coin, dt_prev, dV_prev
        self.prev_dt = None                  # w_{n-2} is not restored
        self.coin_accel = 0.0

    def run(self, protocol: Callable[[float], float] | None = None, end_time_s: float | None = None
            ) -> list[StepRecord]:
        """:meth:`start`, then :meth:`advance` over [0, end] with V = ``protocol(t)``.

        ``protocol`` defaults to the scene's (:func:`scene_protocol`), ``end_time_s`` to
        ``load.end_time_s``. A protocol with ``kinks()`` (:class:`deapull.protocol.Protocol`)
        gets a step that ends on each kink. Step control: Δt = min(Δt, ``time.dt_max_s``, end − t),
        starting from ``time.dt_initial_s``; ×``time.growth`` after an easy step (no
        cut-back and at most 4 Newton iterations per coupling iteration); after a cut-back
        the next step starts from the sub-step size that worked.
        """
        sc = self.scene
        ts = sc.time
        protocol = scene_protocol(sc) if protocol is None else protocol
        end = sc.load.end_time_s if end_time_s is None else float(end_time_s)
        kinks = [k for k in getattr(protocol, "kinks", lambda: [])() if k < end]
        self.start(protocol(0.0))
        dt = ts.dt_initial_s
        dt_uncut = None          # the step size before the last cut-back, grown back to
        bar = tqdm(total=end, disable=not self.progress, unit="s", desc=sc.setup or sc.scene.name,
                   bar_format="{desc}: {percentage:3.0f}%|{bar}| t={n:.3f}/{total:.3f} s [{elapsed}<{remaining}]")
        try:
            while self.t < end * (1 - 1e-12):
                dt = min(dt, ts.dt_max_s, end - self.t)
                ahead = [k - self.t for k in kinks if self.t * (1 + 1e-12) < k < self.t + dt]
                step = min([dt, *ahead])            # land on a kink of V(t) (a hold, a reversal)
                rec = self.advance(protocol(self.t + step), step)
                bar.update(step)
                if rec.cutbacks:
                    dt_uncut = max(dt_uncut or 0.0, dt)
                    dt = self.substep_dt
                elif rec.newton_iterations <= 4 * rec.coupling_iterations:
                    dt *= ts.growth
                elif dt_uncut is not None and dt < dt_uncut:
                    dt = min(dt * ts.growth, dt_uncut)   # back toward the size before the cut-back
                if dt_uncut is not None and dt >= dt_uncut:
                    dt_uncut = None
        finally:
            bar.close()
        if self.steps_below_min_points and self.p.comm.rank == 0:
            log.warning("%d of %d steps had fewer than contact.min_active_points = %d active contact points",
                        self.steps_below_min_points, len(self.records), self.scene.contact.min_active_points)
        return self.records


def as_arrays(records) -> dict[str, np.ndarray]:
    """Column arrays of the records, by field name."""
    names = list(StepRecord.__dataclass_fields__)
    return {n: np.array([getattr(r, n) for r in records]) for n in names}


def coin_travel(records) -> float:
    """The coin's largest |x| (m; it starts at x = 0, so its largest distance from the start; NaN
    without records)."""
    return float(max(abs(r.x) for r in records)) if records else math.nan


def coin_motion(records) -> str:
    """Which way the coin went: toward -x (away from the clamp), toward +x (toward it), or not."""
    if not records:
        return "none"
    x = [r.x for r in records]
    far = max(x, key=abs)
    if abs(far) < 1e-9:
        return "none"
    return "toward -x (away from the clamp)" if far < 0 else "toward +x (toward the clamp)"
