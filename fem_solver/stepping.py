"""Adaptive time stepping over the voltage protocol, with the coin coupled in every step.

Each step: predict the state by linear extrapolation, then iterate DEA solve ↔ coin
update (staggered, secant-accelerated on the coin position) until the coin position
changes by less than ``solver.coupling_tol_m``. The coupling is staggered rather than
monolithic because the coin is one scalar unknown with a non-smooth (stick/slip) law:
dolfinx 0.5 has no global real unknowns, and the fixed point contracts by
Δt²·k/m ≈ 1e-2 (k the DEA tip stiffness), so it converges in a few cheap, warm-started
solves. A failed solve is restored, the step cut by ``time.cutback`` and retried; after
``time.max_cutbacks`` (or below ``time.dt_min_s``) :class:`SolveFailed` is raised with
the time, PETSc's reason and the last good step — nothing is recorded from a failed solve.
"""
from __future__ import annotations

import logging
import math
import time as _time
from dataclasses import asdict, dataclass

import numpy as np
from tqdm import tqdm

from fem_solver.coin import CoinState, coulomb_step, force_balance_residual

log = logging.getLogger(__name__)


class SolveFailed(RuntimeError):
    """The solve could not continue; carries where and why."""

    def __init__(self, t: float, voltage: float, reason: str, last_good_step: int, records):
        self.t, self.voltage, self.reason, self.last_good_step = t, voltage, reason, last_good_step
        self.records = records
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
    stick: int
    force_balance_residual_N: float
    tip_ux: float
    tip_uy: float
    tip_uz: float
    mean_abs_J_minus_1: float
    volume_change: float
    wall_time_s: float


PLACEMENT_MIN_STEP = 1e-3  # smallest gravity-continuation step of the initial placement


def voltage_at(load, t: float) -> float:
    """V(t) of the scene's protocol (ramp: V_max · min(t / ramp_time, 1))."""
    return load.voltage_max_V * min(t / load.ramp_time_s, 1.0)


class Stepper:
    """Runs one scene's problem over [0, end] and collects one record per accepted step.

    Parameters
    ----------
    problem : fem_solver.problem.DEAProblem
    coin_mass_kg : mass of the coin (None when the scene has no coin)
    """

    def __init__(self, problem, coin_mass_kg=None, progress: bool = True, on_step=None):
        self.p, self.scene = problem, problem.scene
        self.mass = coin_mass_kg
        self.coin = CoinState()
        self.records: list[StepRecord] = []
        self.on_step = on_step  # called as on_step(index, t) after each accepted step
        self.progress = progress and problem.comm.rank == 0
        self.coupling_slope = -1.0  # dG/dX of the coin-position fixed point, refined by secants

    # --- one step ------------------------------------------------------------------

    def _coupled_solve(self, V: float, dt: float):
        """DEA ↔ coin iteration for one step; returns (ok, reason, newton its, coupling its, coin)."""
        p, sc = self.p, self.scene
        if sc.coin is None:
            p.set_load(V, 0.0, dt)
            res = p.solve()
            forces = p.obstacle_forces() if res.converged else None
            return res.converged, res.reason, res.iterations, 1, self.coin, forces
        g, mu_b, tol = sc.gravity_m_s2, sc.coin.mu_b, sc.solver.coupling_tol_m
        X = self.coin.x + dt * self.coin.u
        hist = []
        its = 0
        for k in range(1, sc.solver.coupling_max_it + 1):
            p.set_load(V, X, dt)
            res = p.solve()
            its += res.iterations
            if not res.converged:
                return False, res.reason, its, k, None, None
            Fx, Fy = p.obstacle_forces()
            new = coulomb_step(self.coin, Fx, Fy, dt, self.mass, mu_b, g)
            G = new.x - X
            if abs(G) <= tol:
                return True, res.reason, its, k, CoinState(X, new.u, new.stick), (Fx, Fy)
            hist.append((X, G))
            if len(hist) >= 2 and hist[-1][1] != hist[-2][1]:
                (x0, g0), (x1, g1) = hist[-2], hist[-1]
                self.coupling_slope = min(max((g1 - g0) / (x1 - x0), -1e3), -0.1)
            X = X - G / self.coupling_slope
        return False, "COUPLING_NOT_CONVERGED", its, sc.solver.coupling_max_it, None, None

    def _record(self, t, V, dt, its, coupling_its, cutbacks, wall, prev_coin, forces):
        """Append the record of the step just solved (forces from the solve, before accept())."""
        p, sc = self.p, self.scene
        Fx, Fy = forces
        tip = p.tip_displacement()
        residual = 0.0
        if sc.coin is not None and dt > 0:
            residual = force_balance_residual(prev_coin, self.coin, Fx, Fy, dt, self.mass, sc.coin.mu_b,
                                              sc.gravity_m_s2)
        if self.on_step is not None:
            self.on_step(len(self.records), t)
        rec = StepRecord(t=t, x=self.coin.x, u=self.coin.u, V=V, dt=dt, Fx=Fx, Fy=Fy, newton_iterations=its,
                         coupling_iterations=coupling_its, cutbacks=cutbacks, penetration_m=p.max_penetration(),
                         stick=int(self.coin.stick), force_balance_residual_N=residual, tip_ux=tip[0],
                         tip_uy=tip[1], tip_uz=tip[2], mean_abs_J_minus_1=p.mean_volume_change(),
                         volume_change=p.net_volume_change(),
                         wall_time_s=wall)
        values = np.array([v for v in asdict(rec).values()], dtype=float)
        if not np.all(np.isfinite(values)):
            raise SolveFailed(t, V, "NON_FINITE_OUTPUT", len(self.records) - 1, self.records)
        self.records.append(rec)

    def _initial(self):
        """Equilibrium at t = 0 (gravity, V(0)); the first record.

        The DEA is placed on the obstacle without friction: friction acts on slip during a
        step, and placement is not a step of the protocol.
        """
        start = _time.perf_counter()
        V = voltage_at(self.scene.load, 0.0)
        self.p.enable_friction(False)
        its, done, step = 0, 0.0, 1.0
        good = self.p.w.x.array.copy()
        while done < 1.0:
            scale = min(1.0, done + step)
            self.p.gravity_scale.value = scale
            ok, reason, k_its, cits, coin, forces = self._coupled_solve(V, self.scene.time.dt_initial_s)
            its += k_its
            if ok:
                done, step, good[:] = scale, step * 1.5, self.p.w.x.array
                continue
            self.p.w.x.array[:] = good
            step /= 4
            log.info("placement under gravity x %.4g: %s; continuation step cut to %.3g", scale, reason, step)
            if step < PLACEMENT_MIN_STEP:
                raise SolveFailed(0.0, V, f"placement under gravity x {scale:g}: {reason}", -1, self.records)
        self.p.enable_friction(True)
        self.coin = CoinState()
        self._record(0.0, V, 0.0, its, cits, 0, _time.perf_counter() - start, self.coin, forces)
        self.p.accept()
        self.p.accept()  # no history yet: the predictor starts from a constant state

    # --- the loop ------------------------------------------------------------------

    def run(self) -> list[StepRecord]:
        sc = self.scene
        ts, load = sc.time, sc.load
        self._initial()
        t, dt, dt_prev = 0.0, ts.dt_initial_s, None
        bar = tqdm(total=load.end_time_s, disable=not self.progress, unit="s", desc=sc.setup or sc.scene.name,
                   bar_format="{desc}: {percentage:3.0f}%|{bar}| t={n:.3f}/{total:.3f} s [{elapsed}<{remaining}]")
        while t < load.end_time_s * (1 - 1e-12):
            dt = min(dt, ts.dt_max_s, load.end_time_s - t)
            start = _time.perf_counter()
            cutbacks = 0
            while True:
                self.p.predict(0.0 if dt_prev is None else dt / dt_prev)
                V = voltage_at(load, t + dt)
                ok, reason, its, cits, coin, forces = self._coupled_solve(V, dt)
                if ok:
                    break
                self.p.restore()
                cutbacks += 1
                log.info("t = %.6g s, dt = %.3g s: %s after %d Newton iterations; cutting back",
                         t, dt, reason, its)
                dt *= ts.cutback
                if cutbacks > ts.max_cutbacks or dt < ts.dt_min_s:
                    bar.close()
                    raise SolveFailed(t + dt / ts.cutback, V, reason, len(self.records) - 1, self.records)
            prev, self.coin = self.coin, coin
            t += dt
            self._record(t, V, dt, its, cits, cutbacks, _time.perf_counter() - start, prev, forces)
            self.p.accept()
            bar.update(dt)
            dt_prev = dt
            if cutbacks == 0 and its <= 4 * cits:
                dt *= ts.growth
        bar.close()
        return self.records


def as_arrays(records) -> dict[str, np.ndarray]:
    """Column arrays of the records, by field name."""
    names = list(StepRecord.__dataclass_fields__)
    return {n: np.array([getattr(r, n) for r in records]) for n in names}


def coin_travel(records) -> float:
    return float(min((r.x for r in records), default=0.0)) if records else math.nan
