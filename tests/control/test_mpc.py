"""The batched box-iLQR (deapull.control.mpc) against independent solutions: an LQ problem
by a Riccati recursion written here in NumPy, box-constrained problems by brute force on a
grid, box QPs by their KKT conditions, and its derivatives by finite differences."""
from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np
import pytest
import torch

from deapull.control import mpc
from deapull.errors import InputError

F64 = torch.float64


def lq_problem(B=3, T=8, n=4, m=2, seed=0):
    g = torch.Generator().manual_seed(seed)
    A = torch.eye(n, dtype=F64) + 0.2 * torch.randn(n, n, generator=g, dtype=F64)
    Bm = torch.randn(n, m, generator=g, dtype=F64)
    M = torch.randn(n + m, n + m, generator=g, dtype=F64)
    C = M @ M.T / (n + m) + 0.1 * torch.eye(n + m, dtype=F64)
    c = torch.randn(n + m, generator=g, dtype=F64)
    Cf = torch.eye(n, dtype=F64) * 2.0
    cf = torch.randn(n, generator=g, dtype=F64)
    x0 = torch.randn(B, n, generator=g, dtype=F64)
    return A, Bm, mpc.QuadCost(C, c, Cf, cf), x0


def riccati(A, Bm, C, c, Cf, cf, x0, T):
    """Finite-horizon LQR with linear terms (NumPy): optimal u (T, m) from x0."""
    n, m = Bm.shape
    P, p = Cf.copy(), cf.copy()
    Ks, ks = [], []
    for _ in range(T):
        Qxx = C[:n, :n] + A.T @ P @ A
        Quu = C[n:, n:] + Bm.T @ P @ Bm
        Qux = C[n:, :n] + Bm.T @ P @ A
        qx, qu = c[:n] + A.T @ p, c[n:] + Bm.T @ p
        K, k = -np.linalg.solve(Quu, Qux), -np.linalg.solve(Quu, qu)
        P = Qxx + Qux.T @ K
        p = qx + Qux.T @ k
        Ks.insert(0, K)
        ks.insert(0, k)
    x, us = x0, []
    for K, k in zip(Ks, ks):
        us.append(K @ x + k)
        x = A @ x + Bm @ us[-1]
    return np.array(us)


def test_lq_problem_is_solved_exactly_in_one_iteration():
    T = 8
    A, Bm, cost, x0 = lq_problem(T=T)
    sol = mpc.solve(lambda x, u: x @ A.T + u @ Bm.T, cost, x0, torch.zeros(3, T, 2, dtype=F64), iterations=1)
    for b in range(3):
        ref = riccati(*(t.numpy() for t in (A, Bm, cost.C, cost.c, cost.C_final, cost.c_final, x0[b])), T)
        np.testing.assert_allclose(sol.u[b].numpy(), ref, rtol=1e-9, atol=1e-10)
    # further iterations keep it (no step improves on the optimum)
    again = mpc.solve(lambda x, u: x @ A.T + u @ Bm.T, cost, x0, sol.u, iterations=3)
    torch.testing.assert_close(again.u, sol.u, rtol=0, atol=1e-10)


def test_linearize_gives_every_rows_jacobian_in_one_pass():
    def dyn(x, u):
        # data-dependent branches (no vmap possible) and coupling between x and u
        y = torch.where(x[:, :1] > 0, torch.sin(x) * u, x ** 2 + u)
        return y + torch.stack([x[:, 1] * u[:, 0], x[:, 0] ** 3], 1)
    g = torch.Generator().manual_seed(1)
    x, u = torch.randn(2, 5, 2, generator=g, dtype=F64), torch.randn(2, 5, 1, generator=g, dtype=F64)
    A, Bu = mpc.linearize(dyn, x, u)
    for b, t in itertools.product(range(2), range(5)):
        ja, jb = torch.autograd.functional.jacobian(lambda xx, uu: dyn(xx[None], uu[None])[0], (x[b, t], u[b, t]))
        torch.testing.assert_close(A[b, t], ja)
        torch.testing.assert_close(Bu[b, t], jb)


def test_box_qp_meets_the_kkt_conditions():
    g = torch.Generator().manual_seed(2)
    M = torch.randn(200, 3, 3, generator=g, dtype=F64)
    H = M @ M.transpose(-1, -2) + 0.05 * torch.eye(3, dtype=F64)
    q = 3 * torch.randn(200, 3, generator=g, dtype=F64)
    lo, hi = -torch.rand(200, 3, generator=g, dtype=F64), torch.rand(200, 3, generator=g, dtype=F64)
    x, free, ok = mpc.box_qp(H, q, lo, hi)
    assert ok.all()
    grad = (H @ x.unsqueeze(-1))[..., 0] + q
    assert ((x >= lo - 1e-12) & (x <= hi + 1e-12)).all()
    at_lo, at_hi = x <= lo + 1e-9, x >= hi - 1e-9
    assert (grad[free].abs() < 1e-7).all(), grad[free].abs().max()
    assert (grad[at_lo & ~free] > -1e-7).all() and (grad[at_hi & ~free] < 1e-7).all()
    assert (at_lo | at_hi | free).all()


def pendulum(x, u, dt=0.1):
    """A damped pendulum (angle, rate), torque u: nonlinear, bounds matter."""
    th, w = x[:, 0], x[:, 1]
    w_next = w + dt * (-2.0 * torch.sin(th) - 0.3 * w + u[:, 0])
    return torch.stack([th + dt * w_next, w_next], 1)


def test_box_bounds_against_brute_force_on_a_tiny_horizon():
    T, bound = 3, 1.0
    cost = mpc.QuadCost(torch.diag(torch.tensor([4.0, 0.2, 0.05], dtype=F64)),
                        torch.tensor([-4.0 * 1.2, 0.0, 0.0], dtype=F64),  # ½·4(θ − 1.2)² up to a constant
                        torch.diag(torch.tensor([40.0, 1.0], dtype=F64)),
                        torch.tensor([-40.0 * 1.2, 0.0], dtype=F64))
    x0 = torch.tensor([[0.2, 0.0], [1.0, 0.5], [-0.3, 2.0]], dtype=F64)
    sol = mpc.solve(pendulum, cost, x0, torch.zeros(3, T, 1, dtype=F64), -bound, bound, iterations=30, gains=True)
    # a control held at its bound gets no feedback (Tassa et al.'s clamped set)
    at_bound = sol.u.abs() >= bound - 1e-12
    assert not sol.gains.free[at_bound].any() and (sol.gains.K[at_bound[..., 0]] == 0).all()
    grid = torch.linspace(-bound, bound, 81, dtype=F64)
    U = torch.cartesian_prod(grid, grid, grid).reshape(-1, T, 1)
    for b in range(3):
        J = mpc.total_cost(cost, mpc.rollout(pendulum, x0[b].expand(len(U), 2), U), U)
        best = int(J.argmin())
        assert float(sol.cost[b]) <= float(J[best]) + 1e-12
        # the grid's best point lies within one grid spacing of the plan, bounds included
        assert (sol.u[b] - U[best]).abs().max() <= 2 / 80 + 1e-9
    assert (sol.u.abs() <= bound).all() and (sol.u.abs() == bound).any(), "the bounds should be active here"


def test_two_controls_with_bounds_against_brute_force():
    def dyn(x, u):
        return torch.stack([x[:, 0] + 0.5 * u[:, 0] + 0.1 * torch.tanh(u[:, 1]), x[:, 1] + 0.3 * u[:, 1] * u[:, 0]
                            + 0.2 * u[:, 1]], 1)
    cost = mpc.QuadCost(torch.diag(torch.tensor([1.0, 1.0, 0.1, 0.1], dtype=F64)),
                        torch.tensor([-2.0, 1.0, 0.0, 0.0], dtype=F64), torch.eye(2, dtype=F64) * 5,
                        torch.tensor([-10.0, 5.0], dtype=F64))
    lo, hi = torch.tensor([-0.5, -1.0], dtype=F64), torch.tensor([0.8, 0.3], dtype=F64)
    x0 = torch.zeros(1, 2, dtype=F64)
    sol = mpc.solve(dyn, cost, x0, torch.zeros(1, 2, 2, dtype=F64), lo, hi, iterations=40)
    a, b = torch.linspace(-0.5, 0.8, 27, dtype=F64), torch.linspace(-1.0, 0.3, 27, dtype=F64)
    U = torch.cartesian_prod(a, b, a, b)[:, [0, 1, 2, 3]].reshape(-1, 2, 2)
    J = mpc.total_cost(cost, mpc.rollout(dyn, x0.expand(len(U), 2), U), U)
    assert float(sol.cost[0]) <= float(J.min()) + 1e-12
    assert (sol.u[0] - U[int(J.argmin())]).abs().max() <= 1.3 / 26 + 1e-9
    assert ((sol.u >= lo) & (sol.u <= hi)).all()


def test_rows_are_independent_problems_with_their_own_parameters():
    """Row r of every dynamics call belongs to batch row r mod B (per-row parameters)."""
    gain = torch.tensor([0.5, 1.0, 2.0], dtype=F64)

    def dyn(x, u):
        k = gain.repeat(x.shape[0] // 3)
        return torch.stack([x[:, 0] + 0.1 * k * torch.sin(u[:, 0]), x[:, 1] + 0.1 * x[:, 0]], 1)
    cost = mpc.QuadCost(torch.diag(torch.tensor([1.0, 1.0, 0.01], dtype=F64)), torch.tensor([-1.0, 0, 0], dtype=F64))
    x0 = torch.tensor([[0.0, 0.0], [0.1, 0.0], [0.2, -0.1]], dtype=F64)
    together = mpc.solve(dyn, cost, x0, torch.zeros(3, 6, 1, dtype=F64), -1.0, 1.0)
    for b in range(3):
        one = mpc.solve(lambda x, u, b=b: torch.stack([x[:, 0] + 0.1 * gain[b] * torch.sin(u[:, 0]),
                                                      x[:, 1] + 0.1 * x[:, 0]], 1),
                        cost, x0[b:b + 1], torch.zeros(1, 6, 1, dtype=F64), -1.0, 1.0)
        torch.testing.assert_close(together.u[b], one.u[0], rtol=0, atol=1e-10)


def pendulum_problem():
    cost = mpc.QuadCost(torch.diag(torch.tensor([1.0, 0.1, 0.5], dtype=F64)), torch.tensor([-1.0, 0.0, 0.0], dtype=F64),
                        torch.diag(torch.tensor([10.0, 1.0], dtype=F64)), torch.tensor([-10.0, 0.0], dtype=F64))
    return cost, torch.tensor([[0.3, 0.1]], dtype=F64)


def converged(x0, cost, dynamics=pendulum, T=10):
    return mpc.solve(dynamics, cost, x0, torch.zeros(x0.shape[0], T, 1, dtype=F64), -3.0, 3.0, iterations=60,
                     gains=True)


def test_value_gradient_matches_finite_differences():
    cost, x0 = pendulum_problem()
    sol = converged(x0, cost)
    assert sol.gains.free[0, 0].all(), "the test needs u*_0 off its bounds"
    h = 1e-6
    for i in range(2):
        e = torch.zeros_like(x0)
        e[0, i] = h
        up, down = converged(x0 + e, cost), converged(x0 - e, cost)
        dJ = (up.cost[0] - down.cost[0]) / (2 * h)
        # exact (envelope theorem); iLQR's gain K drops the dynamics' second derivatives
        # (15 % off on this pendulum), so K is checked on an LQ problem only
        assert float(dJ) == pytest.approx(float(sol.gains.vx0[0, i]), rel=1e-5, abs=1e-7)
        _, dJ_dx0, _ = mpc.value_and_grad(pendulum, cost, x0, sol.u)
        assert float(dJ) == pytest.approx(float(dJ_dx0[0, i]), rel=1e-5, abs=1e-7)


def test_feedback_gain_is_exact_for_an_lq_problem():
    T = 6
    A, Bm, cost, x0 = lq_problem(B=1, T=T, n=3, m=1, seed=4)
    dyn = lambda x, u: x @ A.T + u @ Bm.T  # noqa: E731
    sol = mpc.solve(dyn, cost, x0, torch.zeros(1, T, 1, dtype=F64), iterations=1, gains=True)
    h = 1e-4
    for i in range(3):
        e = torch.zeros_like(x0)
        e[0, i] = h
        du0 = (mpc.solve(dyn, cost, x0 + e, sol.u, iterations=1).u - mpc.solve(dyn, cost, x0 - e, sol.u,
                                                                               iterations=1).u)[0, 0, 0] / (2 * h)
        assert float(du0) == pytest.approx(float(sol.gains.K[0, 0, 0, i]), rel=1e-7, abs=1e-10)


def test_parameter_gradient_of_the_optimal_cost_matches_finite_differences():
    cost, x0 = pendulum_problem()
    damping = torch.tensor(0.3, dtype=F64, requires_grad=True)

    def dyn(x, u, d=damping):
        w_next = x[:, 1] + 0.1 * (-2.0 * torch.sin(x[:, 0]) - d * x[:, 1] + u[:, 0])
        return torch.stack([x[:, 0] + 0.1 * w_next, w_next], 1)
    sol = converged(x0, cost, dyn)
    _, _, (dJ_dd,) = mpc.value_and_grad(dyn, cost, x0, sol.u, wrt=(damping,))
    h = 1e-5
    Jp = converged(x0, cost, lambda x, u: dyn(x, u, damping.detach() + h)).cost
    Jm = converged(x0, cost, lambda x, u: dyn(x, u, damping.detach() - h)).cost
    assert float((Jp - Jm) / (2 * h)) == pytest.approx(float(dJ_dd), rel=1e-5)


def test_general_cost_matches_the_same_quadratic_cost():
    A, Bm, cost, x0 = lq_problem(B=2, T=5, n=3, m=1, seed=5)
    C, c, Cf, cf = cost.C, cost.c, cost.C_final, cost.c_final
    general = mpc.GeneralCost(lambda x, u, t: 0.5 * torch.cat([x, u]) @ C @ torch.cat([x, u]) + c @ torch.cat([x, u]),
                              lambda x: 0.5 * x @ Cf @ x + cf @ x)
    dyn = lambda x, u: torch.tanh(x @ A.T) + u @ Bm.T  # noqa: E731
    u0 = torch.zeros(2, 5, 1, dtype=F64)
    a, b = mpc.solve(dyn, cost, x0, u0, -1, 1, iterations=8), mpc.solve(dyn, general, x0, u0, -1, 1, iterations=8)
    torch.testing.assert_close(a.u, b.u, rtol=0, atol=1e-12)
    torch.testing.assert_close(a.cost, b.cost)


def test_cost_never_rises_and_the_shifted_plan_warm_starts():
    cost, x0 = pendulum_problem()
    sol = mpc.solve(pendulum, cost, x0, torch.zeros(1, 10, 1, dtype=F64), -3.0, 3.0, iterations=20)
    assert (sol.history[:, 1:] <= sol.history[:, :-1]).all()
    nxt = mpc.shift(sol.u)
    assert torch.equal(nxt[:, :-1], sol.u[:, 1:]) and torch.equal(nxt[:, -1], sol.u[:, -1])
    # from the next state, the shifted plan starts far closer to the optimum than zeros
    cold = mpc.solve(pendulum, cost, sol.x[:, 1], torch.zeros(1, 10, 1, dtype=F64), -3.0, 3.0, iterations=0)
    warm = mpc.solve(pendulum, cost, sol.x[:, 1], nxt, -3.0, 3.0, iterations=0)
    full = mpc.solve(pendulum, cost, sol.x[:, 1], nxt, -3.0, 3.0, iterations=40)
    assert float(warm.cost) - float(full.cost) < 0.05 * (float(cold.cost) - float(full.cost))


# --- the coin task (deapull.control.mpc_policy) -------------------------------------------------

TRUTH_PHI = (1.36e-3, 0.2, 0.5)


@pytest.fixture(scope="module")
def coulomb(committed):
    return committed("f-coulomb")


def test_coin_dynamics_is_the_models_step_in_scaled_units(coulomb):
    from deapull.control.dynamics import CoinDynamics
    from deapull.surrogate.phi import Phi
    phi = Phi(*TRUTH_PHI).to(dtype=F64)
    dyn = CoinDynamics(coulomb, phi, 1e-3, 5.0, 400.0)
    g = torch.Generator().manual_seed(0)
    x = -3e-4 * torch.rand(64, generator=g, dtype=F64)
    u = -0.01 * torch.rand(64, generator=g, dtype=F64)
    V = 400 * torch.rand(64, generator=g, dtype=F64)
    nu = 2 * torch.rand(64, 1, generator=g, dtype=F64) - 1
    V[:4], nu[:4, 0] = torch.tensor([0.0, 2.0, 398.0, 400.0], dtype=F64), torch.tensor([-1.0, -1, 1, 1], dtype=F64)
    xi = torch.cat([dyn.state(float(a), float(b), float(c)) for a, b, c in zip(x, u, V)])
    out = dyn(xi, nu)
    m = dyn.model
    V_next = torch.clamp(V + 5.0 * nu[:, 0], 0, 400)
    stroke, _ = m.material_response(V)
    s, _, _ = m.step(torch.stack([x, u], 1), torch.stack([V_next, torch.full_like(V, 1e-3)], 1),
                     torch.stack([V, stroke], 1), phi)
    torch.testing.assert_close(out[:, 0] * 1e-3, s[:, 0], rtol=1e-12, atol=1e-18)
    torch.testing.assert_close(out[:, 1] * 1e-2, s[:, 1], rtol=1e-12, atol=1e-15)
    torch.testing.assert_close(out[:, 2] * 100, V_next)


def test_paper_cost_is_the_papers_up_to_scale_and_constant():
    from deapull.control.dynamics import coin_cost
    paper, scaled = coin_cost(-1e-3, "paper"), coin_cost(-1e-3, "scaled", dv_weight=0.5)
    xi = torch.tensor([[[-0.4, 0.3, 3.7], [-1.2, 0.0, 0.5]]], dtype=F64)    # mm, 0.01 m/s, 100 V
    nu = torch.tensor([[[0.2], [-1.0]]], dtype=F64)
    x_m, V = xi[..., 0] * 1e-3, xi[..., 2] * 100
    expect = 0.5 * ((x_m + 1e-3) ** 2 + 1e-3 * V ** 2) * 1e6 - 0.5 * 1.0
    torch.testing.assert_close(paper.stage(xi, nu), expect)
    torch.testing.assert_close(scaled.stage(xi, nu), 0.5 * ((xi[..., 0] + 1) ** 2 + 0.5 * nu[..., 0] ** 2) - 0.5)


def episode(policy, env, seed=0):
    from deapull.control.env import policy_view
    obs, info = env.reset(seed=seed)
    policy.reset(env.task_spec())
    actions = []
    while True:
        actions.append(policy.act(obs, policy_view(info)))
        obs, _, terminated, truncated, info = env.step(env.action_of(actions[-1]))
        if terminated or truncated:
            return info, actions


@pytest.mark.parametrize("infer,engine", [(False, "torch"), (False, "auto"), (True, "auto")])
def test_mpc_drives_a_surrogate_plant_to_the_target(coulomb, infer, engine):
    from deapull.control.env import CoinPushEnv
    from deapull.control.plants import SurrogatePlant
    from deapull.control.mpc_policy import MPCConfig, MPCPolicy
    from deapull.surrogate.phi import Phi
    truth = Phi(*TRUTH_PHI)
    env = CoinPushEnv(SurrogatePlant(coulomb, truth), target_m=-2e-4, max_steps=120)
    policy = MPCPolicy(coulomb, MPCConfig(horizon=10, iterations=4, engine=engine, **({} if infer else {"inference": None})), phi=truth)
    info, actions = episode(policy, env)
    assert info["success"], (info["error_m"], info["V_V"])
    # the approach is the ramp at the limit, then the MPC eases off
    assert actions[0] == pytest.approx(5.0) and min(actions[-3:]) < 5.0
    print(f"infer={infer}: reached at step {env.reached_step}, inferred {policy.inferred()}")
    if infer:
        # planned with the estimate, updated every step from the paper's start
        log = policy.inference.log      # one update per step once the coin has moved
        assert 0 < len(log) < env.steps and [r["iteration"] for r in log] == list(range(1, len(log) + 1))
        est = policy.inferred()
        assert all(est[f] != policy.config.inference.start[f] for f in policy.inference.fields)


def test_the_offset_free_mpc_settles_at_every_setpoint_of_push_push_pull_back(coulomb, sweep):
    """The multi-setpoint task on the fixture's surrogate (true φ, no noise), scaled to its
    0.65 mm of travel: push to −0.2 mm, on to −0.4 mm, pull back to −0.3 mm. Each setpoint is
    reached and held inside ±0.01 mm for the whole hold; the pull back needs V to come down
    (the release drags the coin toward the clamp). Broken once: with V kept from falling
    (the MPC's lower bound on ΔV at 0) the third setpoint is never reached."""
    from deapull.control.env import CoinPushEnv
    from deapull.control.mpc_policy import MPCConfig, MPCPolicy
    from deapull.control.plants import SurrogatePlant
    from deapull.workflows.control import run_episode
    plant = SurrogatePlant(coulomb, coulomb.phi_of(sweep["C1"]), name="surrogate:C1")
    env = CoinPushEnv(plant, target_m=-0.2e-3, terminate_on_success=False, max_steps=3000)
    policy = MPCPolicy(coulomb, MPCConfig(horizon=10, iterations=4, inference=None), phi=plant.truth)
    ep = run_episode(env, policy, seed=0, step_limit=800, hold_steps=100, setpoints_m=(-0.2e-3, -0.4e-3, -0.3e-3))
    row = ep.row
    assert (row["setpoints_reached"], row["setpoints_settled"]) == (3, 3), row
    assert row["reached"] and row["settled"] and row["overshoot_m"] < 1e-5
    assert abs(row["final_x_m"] + 0.3e-3) < 1e-5
    assert ep.V_V[-1] < ep.V_V.max() - 10          # the pull back brought the voltage down


def test_with_a_prior_the_plan_uses_only_what_the_data_identify(coulomb, sweep):
    """With the coin-family prior, a field is planned with its estimate only once its
    Cramér–Rao bound is under 10 %; before that, and for fields the data leave unidentified
    (noise 0.1 mm), with the prior's median. Without noise, the bounds fall and the plan takes
    the estimates. Broken once: the plan always taking the estimate (the noisy episode then
    planned with an estimate that is not the prior)."""
    from deapull.control.env import CoinPushEnv
    from deapull.control.inference import COIN_PRIOR, InferenceConfig
    from deapull.control.mpc_policy import MPCConfig, MPCPolicy
    from deapull.control.plants import SurrogatePlant
    from deapull.workflows.control import run_episode
    plant = SurrogatePlant(coulomb, coulomb.phi_of(sweep["C1"]), name="surrogate:C1")
    config = MPCConfig(horizon=10, iterations=4,
                       inference=InferenceConfig(optimizer="lm", prior=COIN_PRIOR, crlb_every=25))
    planned = {}
    for sigma in (0.0, 1e-4):
        env = CoinPushEnv(plant, target_m=-0.4e-3, terminate_on_success=False, max_steps=300, noise_std_m=sigma)
        policy = MPCPolicy(coulomb, config)
        run_episode(env, policy, seed=0, step_limit=250, hold_steps=20)
        est, phi = policy.inferred(), policy.dynamics.phi
        planned[sigma] = {f: (phi.value(f), est[f], est[f"crlb_{f}"]) for f in policy.inference.fields}
    for f, (plan, est, bound) in planned[1e-4].items():
        assert bound > 0.1 and plan == pytest.approx(COIN_PRIOR[f][0], rel=1e-12) and est != plan, (f, planned)
    identified = [f for f, (_, _, bound) in planned[0.0].items() if bound < 0.1]
    assert identified, planned
    for f in identified:
        assert planned[0.0][f][0] == pytest.approx(planned[0.0][f][1], rel=1e-12)


@pytest.mark.parametrize("field, value", [("creep_V", -0.5), ("approach_m", float("nan")), ("standoff_stds", -1.0),
                                          ("rate_V", -0.4), ("horizon", 0), ("iterations", 1.5), ("cost", "cheap"),
                                          ("engine", "gpu")])
def test_bad_mpc_settings_are_refused_naming_the_field(field, value):
    from deapull.control.mpc_policy import MPCConfig
    with pytest.raises(InputError, match=field.replace("_", "[ _]")):
        MPCConfig(**{field: value})


def test_near_the_target_the_approach_limit_slows_the_push_and_small_steps_creep(coulomb, sweep):
    """With ``approach_m`` the planned |ΔV| within that distance of the target is at most
    ΔV_max × distance / approach_m, never below the 0.5 V creep; without it the MPC arrives at
    the full 5 V per step. Broken once: the limit left out (the first check failed)."""
    from deapull.control.env import CoinPushEnv, policy_view
    from deapull.control.mpc_policy import MPCConfig, MPCPolicy
    from deapull.control.plants import SurrogatePlant
    plant = SurrogatePlant(coulomb, coulomb.phi_of(sweep["C1"]), name="surrogate:C1")
    largest_near = {}
    for approach in (0.0, 0.2e-3):
        env = CoinPushEnv(plant, target_m=-0.4e-3, terminate_on_success=False, max_steps=400)
        policy = MPCPolicy(coulomb, MPCConfig(horizon=10, iterations=4, inference=None, approach_m=approach),
                           phi=plant.truth)
        obs, info = env.reset(seed=0)
        policy.reset(env.task_spec())
        near = []
        for _ in range(300):
            d = abs(env.state[0] + 0.4e-3)
            dV = policy.act(obs, policy_view(info))
            if approach and d < approach and dV:
                # (the policy sees x as a float32 observation: a volt's thousandth of slack)
                assert abs(dV) <= max(0.5, 5.0 * d / approach) + 1e-3, (d, dV)
                assert abs(dV) >= 0.5 - 1e-9
            if d < 0.2e-3:
                near.append(abs(dV))
            obs, _, _, _, info = env.step(env.action_of(dV))
        largest_near[approach] = max(near)
    assert largest_near[0.0] == pytest.approx(5.0) and largest_near[0.2e-3] < 5.0


def test_under_noise_the_stand_off_holds_short_of_the_target_until_the_estimate_has_averaged(coulomb, sweep, monkeypatch):
    """With ``standoff_stds`` at σ = 0.1 mm the MPC stops short on the side the coin comes from
    and holds V (the estimate's std falls as the observations average), then goes on: it
    waits, and the coin never passes the target's window on the way. Broken once: no stand-off
    (the policy never waited)."""
    from deapull.control import mpc_policy
    monkeypatch.setattr(mpc_policy, "MAX_WAIT", 1200)
    from deapull.control.env import CoinPushEnv
    from deapull.control.mpc_policy import MPCConfig, MPCPolicy
    from deapull.control.plants import SurrogatePlant
    from deapull.workflows.control import run_episode
    plant = SurrogatePlant(coulomb, coulomb.phi_of(sweep["C1"]), name="surrogate:C1")
    env = CoinPushEnv(plant, target_m=-0.4e-3, terminate_on_success=False, max_steps=2000, noise_std_m=1e-4)
    policy = MPCPolicy(coulomb, MPCConfig(horizon=10, iterations=4, inference=None, standoff_stds=2.0),
                       phi=plant.truth)
    row = run_episode(env, policy, seed=0, step_limit=1800, hold_steps=50).row
    assert policy.waited > 50
    assert row["overshoot_m"] < 1e-5


def test_the_rate_schedule_is_fast_below_the_onset_and_the_cruise_rate_once_the_coin_moves(coulomb, sweep,
                                                                                            monkeypatch):
    """``rate_V`` (the rate schedule): the MPC plans with that ΔV_max and, once the coin moves,
    applies no step larger; below the onset, where f_a pushed at the plant's full rate leaves the coin
    standing for ``MARGIN_V`` more, it steps at the full 5 V, so it reaches sooner than at 0.4 V all
    the way and still holds. Without ``rate_V`` the MPC pushes at 5 V per step throughout. Broken
    once: the fast start left out (every step at 0.4 V, no faster reach: the last checks failed)."""
    from deapull.control import mpc_policy
    from deapull.control.env import CoinPushEnv
    from deapull.control.mpc_policy import MPCConfig, MPCPolicy
    from deapull.control.plants import SurrogatePlant
    from deapull.workflows.control import run_episode
    plant = SurrogatePlant(coulomb, coulomb.phi_of(sweep["C1"]), name="surrogate:C1")
    largest, fast, reached = {}, {}, {}
    for label, rate, start in (("plant", 0.0, True), ("schedule", 0.4, True), ("capped", 0.4, False)):
        if not start:
            monkeypatch.setattr(mpc_policy.MPCPolicy, "_below_onset", lambda self, *a: False)
        env = CoinPushEnv(plant, target_m=-0.4e-3, terminate_on_success=False, max_steps=2000)
        policy = MPCPolicy(coulomb, MPCConfig(horizon=10, iterations=4, inference=None, rate_V=rate),
                           phi=plant.truth)
        episode = run_episode(env, policy, seed=0, step_limit=1800, hold_steps=50)
        V, x = np.asarray(episode.V_V), np.asarray(episode.x_m)
        steps = np.abs(np.diff(V))
        moving = np.abs(x[:-1]) > 0                       # the coin has left its start before the step
        largest[label] = float(steps[moving].max())
        fast[label] = int((steps > 0.4 + 1e-9).sum())
        reached[label] = episode.row["iterations_to_target"]
        assert episode.row["reached"] and episode.row["settled"], (label, episode.row)
    assert largest["plant"] == pytest.approx(5.0)
    assert largest["schedule"] <= 0.4 + 1e-9 and largest["capped"] <= 0.4 + 1e-9
    assert fast["schedule"] > 10 and fast["capped"] == 0
    assert reached["schedule"] < 0.8 * reached["capped"], reached


def test_the_approach_taper_gives_way_at_the_edge_of_the_reach(coulomb, sweep):
    """``approach_m`` slows the push near the target, and on a coin whose travel grows with the
    push rate (the fixture surrogate: 0.648 mm at 0.4 V per step, 0.461 mm at 0.1) the slower
    push costs the last µm: a target 3 µm inside the 0.4 V reach (−0.645 mm) was never reached
    (the coin stopped at −0.634 mm at 400 V, 0.9 µm outside). The policy therefore skips the
    taper while its model, pushed at the full rate to 400 V, stops within the tolerance past
    the target; well inside the reach (−0.5 mm) it tapers as before (reached below 400 V).
    Broken once: with the reach check off (the taper always applied) the −0.645 mm episode
    failed exactly so."""
    from deapull.control.env import CoinPushEnv
    from deapull.control.mpc_policy import MPCConfig, MPCPolicy
    from deapull.control.plants import SurrogatePlant
    from deapull.workflows.control import run_episode
    plant = SurrogatePlant(coulomb, coulomb.phi_of(sweep["C1"]), name="surrogate:C1")
    config = MPCConfig(horizon=10, iterations=4, inference=None, rate_V=0.4, approach_m=1e-4, creep_V=0.1)
    rows = {}
    for target in (-0.645e-3, -0.5e-3):
        env = CoinPushEnv(plant, target_m=target, terminate_on_success=False, max_steps=3000)
        rows[target] = run_episode(env, MPCPolicy(coulomb, config, phi=plant.truth), seed=0, step_limit=2800,
                                   hold_steps=100).row
    assert rows[-0.645e-3]["settled"], rows[-0.645e-3]
    assert rows[-0.5e-3]["settled"] and rows[-0.5e-3]["final_V_V"] < 350, rows[-0.5e-3]


def test_a_coin_the_model_holds_averages_down_while_the_voltage_creeps(coulomb, sweep):
    """A coin f_a says stands (here below its onset) is held by static friction whether or not
    the voltage creeps, so the offset-free filter adds no process noise for that step and the
    estimate's std falls as σ/√n: 200 observations at σ = 0.1 mm give ≈ 7 µm. This is what lets
    the chance constraint close on the target while the policy creeps toward it (surrogate:C5 from
    C5's ramp, noise 1e-4: episode 1 reached in 581 iterations against 1,142). Broken once (held
    only where V did not change, as before): the std stalled at the process noise's floor, 10 µm."""
    from deapull.control.env import CoinPushEnv
    from deapull.control.mpc_policy import MPCConfig, MPCPolicy
    from deapull.control.plants import SurrogatePlant
    plant = SurrogatePlant(coulomb, coulomb.phi_of(sweep["C1"]), name="surrogate:C1")
    env = CoinPushEnv(plant, target_m=-0.4e-3, terminate_on_success=False, noise_std_m=1e-4)
    env.reset(seed=0)
    policy = MPCPolicy(coulomb, MPCConfig(inference=None, standoff_stds=2.0), phi=plant.truth)
    policy.reset(env.task_spec())
    rng = np.random.default_rng(0)
    x_true, V = -50e-6, 10.0
    for _ in range(200):
        x, u = policy._estimate(x_true + 1e-4 * rng.standard_normal(), V)
        policy.previous = (x, u, V)
        V += 0.1                                   # creeping, far below the onset
    assert u == 0.0
    assert policy.estimate_std_m < 8e-6, policy.estimate_std_m


def test_the_aim_is_a_chance_constraint_that_closes_as_the_estimate_averages(coulomb, sweep):
    """The stand-off aims ``standoff_stds`` × σ − tolerance short of the target on the side the coin
    comes from (``_aim``): 2 × 8 − 10 = 6 µm short at σ = 8 µm, and at the target once σ is at
    most tolerance / ``standoff_stds`` (5 µm). Broken once (the tolerance left out of the margin):
    the aim stood 16 µm short."""
    from deapull.control.env import CoinPushEnv
    from deapull.control.mpc_policy import MPCConfig, MPCPolicy
    from deapull.control.plants import SurrogatePlant
    plant = SurrogatePlant(coulomb, coulomb.phi_of(sweep["C1"]), name="surrogate:C1")
    env = CoinPushEnv(plant, target_m=-0.4e-3, terminate_on_success=False, noise_std_m=1e-4)
    env.reset(seed=0)
    policy = MPCPolicy(coulomb, MPCConfig(inference=None, standoff_stds=2.0), phi=plant.truth)
    policy.reset(env.task_spec())
    policy.bias.reset(-0.3e-3)
    aims = {}
    for std in (8e-6, 5e-6, 2e-6):
        policy.bias.P[0, 0] = std ** 2
        x = -0.3e-3
        aims[std] = policy._aim(policy.dynamics.state(x, 0.0, 100.0, None), x, 100.0)
    assert aims[8e-6] == pytest.approx(-0.4e-3 + 6e-6)
    assert aims[5e-6] == aims[2e-6] == -0.4e-3


def test_the_stand_off_gives_way_at_the_edge_of_the_reach(coulomb, sweep, monkeypatch):
    """The stand-off parks the coin short of the target while the estimate averages down; at the
    edge of the reach (−0.645 mm, 3 µm inside the fixture surrogate's 0.4 V-per-step travel) the
    parked coin never gets there (it stood short for the rest of the episode), as fem:C7 at
    resolved did. So where :meth:`MPCPolicy._at_reach` holds the policy aims at the target
    itself: it settles, having waited a few steps at most; well inside the reach (−0.5 mm) it
    still waits at the stand-off. Broken once: with the reach left out of the stand-off the
    −0.645 mm episode waited 800 steps (max_wait then) and was never reached (the first check failed). The reach
    is rolled out once per step, though the stand-off and the taper both ask (broken once: without
    the step's memo, steps of the −0.645 mm episode rolled it out twice)."""
    from deapull.control import mpc_policy
    monkeypatch.setattr(mpc_policy, "MAX_WAIT", 1200)
    import collections

    from deapull.control.env import CoinPushEnv
    from deapull.control.mpc_policy import MPCConfig, MPCPolicy
    from deapull.control.plants import SurrogatePlant
    from deapull.workflows.control import run_episode
    plant = SurrogatePlant(coulomb, coulomb.phi_of(sweep["C1"]), name="surrogate:C1")
    config = MPCConfig(horizon=10, iterations=4, inference=None, rate_V=0.4, approach_m=1e-4, creep_V=0.1,
                       standoff_stds=2.0)
    rows, waited = {}, {}
    for target in (-0.645e-3, -0.5e-3):
        env = CoinPushEnv(plant, target_m=target, terminate_on_success=False, max_steps=3000, noise_std_m=1e-4)
        policy = MPCPolicy(coulomb, config, phi=plant.truth)
        reach_rolls, roll = collections.Counter(), policy._roll

        def counted(xi0, nu, roll=roll, policy=policy, rolls=reach_rolls):
            if nu.shape[1] > config.horizon:            # the full-rate push to the voltage limit
                rolls[len(policy.solve_ms)] += 1        # keyed by the step
            return roll(xi0, nu)

        policy._roll = counted
        rows[target] = run_episode(env, policy, seed=0, step_limit=2800, hold_steps=100).row
        waited[target] = policy.waited
        if target == -0.645e-3:
            assert reach_rolls and max(reach_rolls.values()) == 1, reach_rolls.most_common(3)
    assert rows[-0.645e-3]["settled"] and waited[-0.645e-3] < 50, (rows[-0.645e-3], waited)
    # well inside the reach it waits at the stand-off (42 steps here) while the estimate averages down
    assert waited[-0.5e-3] > 20, (rows[-0.5e-3], waited)


def test_the_reach_gate_can_be_switched_off(coulomb, sweep):
    """One 0.4 V step below the voltage limit and 5 µm short of the target, the policy judges the
    target at the edge of the reach, so the stand-off and the taper give way (the test above).
    With ``reach_gate=False`` (``--mpc-no-reach-gate``) it never does: on the surrogates at 5 V per
    step the prior's median put −1 mm at C1's edge and the coin ran past (docs/control.md, tenth
    session). Broken once (the flag ignored): the gate-off case judged True as well."""
    from deapull.control.env import CoinPushEnv
    from deapull.control.mpc_policy import MPCConfig, MPCPolicy
    from deapull.control.plants import SurrogatePlant
    plant = SurrogatePlant(coulomb, coulomb.phi_of(sweep["C1"]), name="surrogate:C1")
    target, V = -0.645e-3, 399.6
    judged = {}
    for gate in (True, False):
        config = MPCConfig(horizon=10, iterations=4, inference=None, rate_V=0.4, approach_m=1e-4, creep_V=0.1,
                           standoff_stds=2.0, reach_gate=gate)
        env = CoinPushEnv(plant, target_m=target, terminate_on_success=False, max_steps=3000, noise_std_m=1e-4)
        env.reset(seed=0)
        policy = MPCPolicy(coulomb, config, phi=plant.truth)
        policy.reset(env.task_spec())
        x = target + 5e-6
        judged[gate] = policy._at_reach(policy.dynamics.state(x, 0.0, V, None), x, V)
    assert judged == {True: True, False: False}


@pytest.mark.parametrize("off_um, expected", [(2.0, "hold"), (7.0, "creep"), (9.0, "creep")])
def test_a_coin_standing_outside_the_hold_band_creeps_even_inside_the_tolerance(fs1_model, monkeypatch, off_um,
                                                                               expected):
    """A coin at rest ``off_um`` short of the target whose solved plan leaves V where it is: within
    the hold band (5 µm) the policy holds; outside it, even inside the 10 µm tolerance, it creeps
    toward the target. Between the two it used to do neither, and on fem:C1 (f-memory f_a, the
    stand-off) the coin stood 10.2 µm short for 2,500 steps on an estimate 7–8 µm off (docs/control.md).
    Broken once (the stall judged against the tolerance, as before): the 7 µm case returned 0."""
    from types import SimpleNamespace

    from deapull.control.env import CoinPushEnv
    from deapull.control.mpc_policy import MPCConfig, MPCPolicy
    from deapull.surrogate.phi import Phi
    from tests.control.conftest import ParkedPlant

    def standing_plan(dynamics, cost, x0, u_init, lower=None, upper=None, **kwargs):
        states = x0.unsqueeze(1).repeat(1, u_init.shape[1] + 1, 1).clone()
        states[:, :, 1] = 0.0                                  # the coin stands along the plan
        return SimpleNamespace(cost=torch.zeros(x0.shape[0], dtype=x0.dtype), u=torch.zeros_like(u_init), x=states)

    monkeypatch.setattr(mpc, "solve", standing_plan)
    target = -0.4e-3
    env = CoinPushEnv(ParkedPlant(target + off_um * 1e-6), target_m=target, terminate_on_success=False)
    config = MPCConfig(inference=None, engine="torch")
    policy = MPCPolicy(fs1_model, config, phi=Phi(1.36e-3, 0.2, 0.5))
    obs, info = env.reset(seed=0)
    policy.reset(env.task_spec())
    dV = policy.act(obs, info)
    assert policy.holding == (expected == "hold")
    assert dV == (0.0 if expected == "hold" else pytest.approx(config.creep_V))


def test_a_repeated_task_learns_the_final_voltage_and_the_gain_and_the_episodes_get_faster(coulomb, sweep, monkeypatch):
    """``learn`` (iterative learning control): episode 1 at σ = 0.1 mm with the stand-off ends settled
    and leaves its final voltage and g; the next episodes play the rate schedule to the voltage where
    the landing line meets the target, and hold: on the fixture 91 iterations (held 300 steps, so that
    its estimate averages down to a landing), then 71, 71, none past the window, where the same
    policy without learning takes 91, 484 and 232. Another noise is another task. Broken once: the schedule left out (the second
    episode took as long as the first); and once with a turn counted wherever V first fell (short
    of the target too), so that the line started from where episode 1 turned on its way (545
    iterations for the second)."""
    from deapull.control import mpc_policy
    monkeypatch.setattr(mpc_policy, "MAX_WAIT", 1200)
    from deapull.control.env import CoinPushEnv
    from deapull.control.mpc_policy import MPCConfig, MPCPolicy
    from deapull.control.plants import SurrogatePlant
    from deapull.workflows.control import run_episode
    plant = SurrogatePlant(coulomb, coulomb.phi_of(sweep["C1"]), name="surrogate:C1")
    env = CoinPushEnv(plant, target_m=-0.4e-3, terminate_on_success=False, max_steps=2000, noise_std_m=1e-4)
    config = MPCConfig(horizon=10, iterations=4, inference=None, standoff_stds=2.0, approach_m=1e-4)
    policy = MPCPolicy(coulomb, config, phi=plant.truth)
    first = run_episode(env, policy, seed=0, step_limit=1800, hold_steps=300).row
    gain, V_end = policy.bias.gain, policy.previous[2]
    assert policy.learned == {}                  # learnt when the next episode starts
    second = run_episode(env, policy, seed=1, step_limit=1800, hold_steps=50).row
    (learned,) = policy.learned.values()
    assert learned["gain"] == gain and abs(learned["V_f"] - V_end) < 10 and V_end > 100
    third = run_episode(env, policy, seed=2, step_limit=1800, hold_steps=50).row
    rows = (first, second, third)
    assert all(r["settled"] and r["overshoot_m"] < 1e-5 for r in rows), rows
    learnt = max(second["iterations_to_target"], third["iterations_to_target"])
    assert learnt < 0.9 * first["iterations_to_target"]
    other = MPCPolicy(coulomb, replace(config, learn=False), phi=plant.truth)
    for seed in range(3):
        again = run_episode(env, other, seed=seed, step_limit=1800, hold_steps=300 if seed == 0 else 50).row
    assert again["iterations_to_target"] > 1.1 * learnt and other.learned == {}


def test_an_episode_that_ends_within_the_approach_distance_starts_the_landing_line(coulomb, sweep):
    """The landing line weighs each point by its variance, so an episode whose converged estimate
    ends off the window but within the approach distance (where f_a's slope is the line's prior) is a
    point of it: 15 µm from the target with a std of 8 µm starts the line with ``approach_m`` = 0.1 mm,
    not without an approach distance (then the tolerance bounds it), and 150 µm off does not. Broken
    once (the tolerance as the bound whatever the approach distance): nothing was learnt."""
    from deapull.control.env import CoinPushEnv
    from deapull.control.mpc_policy import MPCConfig, MPCPolicy
    from deapull.control.plants import SurrogatePlant
    from deapull.workflows.control import run_episode
    plant = SurrogatePlant(coulomb, coulomb.phi_of(sweep["C1"]), name="surrogate:C1")
    env = CoinPushEnv(plant, target_m=-0.4e-3, terminate_on_success=False, max_steps=400, noise_std_m=1e-4)

    def learnt(approach_m: float, off_m: float) -> bool:
        policy = MPCPolicy(coulomb, MPCConfig(horizon=10, iterations=4, inference=None, approach_m=approach_m),
                           phi=plant.truth)
        run_episode(env, policy, seed=0, step_limit=300, hold_steps=20)
        V = policy.previous[2]
        assert V > 100                     # the coin has moved: f_a has a slope there
        policy.previous, policy.turned, policy.landing = (-0.4e-3 + off_m, 0.0, V), None, None
        policy.bias.P[0, 0] = 8e-6 ** 2
        policy._learn()
        return bool(policy.learned)

    assert learnt(1e-4, 15e-6) and learnt(1e-4, -15e-6)
    assert not learnt(0.0, 15e-6) and not learnt(1e-4, 150e-6)


def test_a_target_the_landing_line_meets_beyond_the_voltage_limit_is_planned_not_scheduled(coulomb, sweep):
    """Where the landing line stays outside the window even at the voltage limit, a schedule cannot
    reach the target (surrogate:C2 on the data fidelity, trained on an AMD EPYC: the plan's push
    coasted to the target at 397.5 V, the schedules stopped 36–58 µm short at 400 V, and 9 of 10
    episodes missed). Here the first episode ends 30 µm short of the target at the voltage limit (the
    limit set to its end voltage): the task is marked beyond the schedule's reach, the next episode
    plans, and nothing is learnt for it after. Ending 8 µm short there, inside the window, starts a
    schedule to the limit (surrogate:C2 trained on an Intel Xeon at σ = 0.1 mm: episodes 2–10
    settled 9/9 with a median of 83 iterations, against 314 when such a task was planned). With the
    limit 20 V higher the 8 µm end starts a schedule below it, and a scheduled episode whose hold then
    went to the limit 30 µm short marks the task (5 µm short, inside the window, is a landing).
    A marked task is planned without the approach taper (surrogate:C2 noise-free, data fidelity:
    0/10 reached with it, 9/10 without it after the first episode).
    Broken once with each rule left out or widened: the 30 µm end was scheduled; the 8 µm end at the
    limit was marked (any line meeting the target beyond the limit, as before); the short landing
    joined the line."""
    from deapull.control import mpc_policy
    from deapull.control.env import CoinPushEnv
    from deapull.control.mpc_policy import BEYOND_REACH, MPCConfig, MPCPolicy
    from deapull.control.plants import SurrogatePlant
    from deapull.workflows.control import run_episode
    plant = SurrogatePlant(coulomb, coulomb.phi_of(sweep["C1"]), name="surrogate:C1")
    env = CoinPushEnv(plant, target_m=-0.4e-3, terminate_on_success=False, max_steps=400)

    def learnt(headroom_V: float, short_m: float = 8e-6):
        policy = MPCPolicy(coulomb, MPCConfig(horizon=10, iterations=4, inference=None, approach_m=1e-4),
                           phi=plant.truth)
        run_episode(env, policy, seed=0, step_limit=300, hold_steps=20)
        V = policy.previous[2]
        assert V > 100                     # the coin has moved: f_a has a slope there
        policy.previous, policy.turned, policy.landing = (-0.4e-3 + short_m, 0.0, V), None, None
        policy.v_max_V = V + headroom_V
        policy._learn()
        return policy, next(iter(policy.learned.values()), None)

    policy, entry = learnt(0.0, 30e-6)
    assert entry is BEYOND_REACH and policy.approach_m == 1e-4
    policy.reset(env.task_spec())
    # planned, and at the full rate: at the edge of the plant's reach the taper costs the last µm
    assert policy.schedule is None and policy.approach_m == 0.0
    policy._learn()
    assert list(policy.learned.values()) == [BEYOND_REACH]
    policy, entry = learnt(0.0)
    assert entry is not BEYOND_REACH and entry["V_f"] == policy.v_max_V
    policy, entry = learnt(20.0)
    assert entry is not BEYOND_REACH and entry["V_f"] < policy.v_max_V
    # a scheduled episode whose hold went to the voltage limit: within the window it is a landing,
    # 30 µm short it marks the task (the schedule cannot reach it)
    for short_m, marked in ((5e-6, False), (30e-6, True)):
        learned = {k: dict(v, landings=list(v["landings"])) for k, v in policy.learned.items()}
        policy.previous, policy.landing = (-0.4e-3 + short_m, 0.0, policy.v_max_V), {"n": 4, "sum": 4 * (-0.4e-3 + short_m),
                                                                                    "V_f": entry["V_f"]}
        policy._learn()
        assert (next(iter(policy.learned.values())) is BEYOND_REACH) == marked
        policy.learned = learned
    assert mpc_policy.BEYOND_REACH is BEYOND_REACH


@pytest.mark.parametrize("noise_m, target_m, restrokes", [(0.0, -0.2e-3, 2), (1e-3, -0.182e-3, 1)])
def test_a_coin_standing_short_of_the_target_at_the_voltage_limit_is_restroked_at_the_creep_rate(
        coulomb, sweep, monkeypatch, noise_m, target_m, restrokes):
    """With the voltage limit at 250 V the fixture's plant (f-coulomb on C1) stands at 170.4 µm, short of
    a 200 µm target: no voltage is left to push on. Backing off 5 V and creeping up at 0.5 V per step
    carries it further each time (a quasi-static push slides it on where the planned rate left it):
    two restrokes reach the window. In a sweep (σ = 1 mm), which cannot tell where the coin stands,
    one restroke of 2 V takes it from 1.6 µm short of a 182 µm target's window into it, and there is
    no second. A coin standing inside the window (170 µm target) is not restroked. A restroked task is
    planned without the approach taper in later episodes (the plant showed the target at the edge of its
    reach). Broken once each: without the restroke (RESTROKE_MAX = 0) neither reaches; with the sweep's cap
    lifted it restroked 3 times; restroking whatever the coin's mean at the limit, 3 times; without the
    mark, the next episode learnt a schedule."""
    from deapull.control import mpc_policy
    from deapull.control.env import CoinPushEnv
    from deapull.control.mpc_policy import MPCConfig, MPCPolicy
    from deapull.control.plants import SurrogatePlant
    from deapull.workflows.control import run_episode
    plant = SurrogatePlant(coulomb, coulomb.phi_of(sweep["C1"]), name="surrogate:C1")

    def episode(target, noise=noise_m):
        env = CoinPushEnv(plant, target_m=target, v_max_V=250.0, noise_std_m=noise, terminate_on_success=False,
                          max_steps=400)
        policy = MPCPolicy(coulomb, MPCConfig(horizon=10, iterations=4, inference=None, approach_m=1e-4),
                           phi=plant.truth)
        return run_episode(env, policy, seed=0, step_limit=400, hold_steps=20), policy, env

    ep, policy, env = episode(target_m)
    assert ep.row["reached"] and policy.restrokes == restrokes
    assert float(ep.V_V.max()) == 250.0
    if noise_m == 0:
        # the target lies at the edge of the reach: the next episodes plan without the approach taper
        policy.reset(env.task_spec())
        assert list(policy.learned.values()) == [mpc_policy.BEYOND_REACH] and policy.approach_m == 0.0
        ep, policy, _ = episode(-0.17e-3)
        assert ep.row["reached"] and policy.restrokes == 0
    monkeypatch.setattr(mpc_policy, "RESTROKE_MAX", 0)
    ep, policy, _ = episode(target_m)
    assert not ep.row["reached"] and policy.restrokes == 0


def test_the_stand_off_does_not_wait_where_the_noise_cannot_be_averaged_down_in_time(coulomb, sweep):
    """At σ = 1 mm the held observations average the estimate to σ/√max_wait = 26 µm at best, far
    above the stand-off's 0.3 × 10 µm: waiting cannot help, so the MPC does not stand off (at
    σ = 0.1 mm it does: the test above). Broken once: the rule left out (it stood off for 48 steps)."""
    from deapull.control.env import CoinPushEnv
    from deapull.control.mpc_policy import MPCConfig, MPCPolicy
    from deapull.control.plants import SurrogatePlant
    from deapull.workflows.control import run_episode
    plant = SurrogatePlant(coulomb, coulomb.phi_of(sweep["C1"]), name="surrogate:C1")
    env = CoinPushEnv(plant, target_m=-0.4e-3, terminate_on_success=False, max_steps=2000, noise_std_m=1e-3)
    policy = MPCPolicy(coulomb, MPCConfig(horizon=10, iterations=4, inference=None, standoff_stds=2.0),
                       phi=plant.truth)
    run_episode(env, policy, seed=0, step_limit=1800, hold_steps=50)
    assert policy._unresolvable() and policy.waited == 0


def test_the_learnt_schedule_lands_where_the_landings_say(coulomb, sweep):
    """Iterative learning on the end voltage: each learnt episode's held observations of where the
    schedule landed join the landing line, and the next end voltage is where the line meets the
    target. Noise-free on the fixture's surrogate the third episode lands on the target to the
    line's accuracy, closer than the second (the first episode's end on its own path, moved
    by f_a's slope). Broken once (the landings left out of the fit): every learnt episode lands
    where the second did, 0.12 µm off."""
    from deapull.control.env import CoinPushEnv
    from deapull.control.mpc_policy import MPCConfig, MPCPolicy
    from deapull.control.plants import SurrogatePlant
    from deapull.workflows.control import run_episode
    plant = SurrogatePlant(coulomb, coulomb.phi_of(sweep["C1"]), name="surrogate:C1")
    env = CoinPushEnv(plant, target_m=-0.4e-3, terminate_on_success=False, max_steps=2000)
    policy = MPCPolicy(coulomb, MPCConfig(horizon=10, iterations=4, inference=None, approach_m=1e-4), phi=plant.truth)
    rows = [run_episode(env, policy, seed=k, step_limit=1800, hold_steps=50).row for k in range(4)]
    (learned,) = policy.learned.values()
    assert len(learned["landings"]) == 2                  # episodes 2 and 3 (episode 4's joins at the next reset)
    landed = [V_x[1] for V_x in learned["landings"]]
    errors = [abs(x + 0.4e-3) for x in landed]
    assert errors[1] < 0.5 * errors[0] and errors[1] < 2e-6
    assert all(r["settled"] for r in rows[2:])



def test_the_landing_line_learns_a_slope_that_f_a_has_wrong(coulomb, sweep):
    """Near the end of the reach f_a's slope of the landing can be a quarter of the plant's; it is the
    landing line's prior only. The points are a recorded run (surrogate preset, surrogate:C1 at
    σ = 0.1 mm, episode 6: episode 1's end at 400 V and four landings' means), f_a's slope
    −3.06 µm/V; the plant's own landings, read off the episodes that held where they landed, lie at
    −11 µm/V. The next end voltage puts the plant's landing inside the ±10 µm window (399.20 V,
    5 µm past). Broken once (the prior's std at half f_a's slope, as before): 399.91 V, 13 µm past."""
    from deapull.control.mpc_policy import MPCConfig, MPCPolicy
    from deapull.control.plants import SurrogatePlant
    plant = SurrogatePlant(coulomb, coulomb.phi_of(sweep["C1"]), name="surrogate:C1")
    policy = MPCPolicy(coulomb, MPCConfig(horizon=10, iterations=4, inference=None), phi=plant.truth)
    policy.target_m, policy.v_max_V = -1e-3, 400.0
    um = 1e-6
    (V0, x0, s0), *landings = [(400.0, -1028.4, 12.1), (390.72, -882.2, 31.6), (396.84, -980.9, 9.5),
                               (399.0, -988.9, 10.2), (399.76, -997.5, 10.2)]
    entry = {"slope": -3.06 * um, "start": (V0, x0 * um, (s0 * um) ** 2),
             "landings": [(V, x * um, (s * um) ** 2) for V, x, s in landings]}
    V_f, x_f, _ = policy._landing_fit(entry)
    plant_V = [398.5, 398.62, 399.0, 399.2, 399.33, 399.76, 399.9]
    plant_x = [-997.1, -998.4, -1002.7, -1005.0, -1006.5, -1011.4, -1013.0]
    assert abs(np.interp(V_f, plant_V, plant_x) + 1000.0) < 10.0 and x_f == pytest.approx(-1e-3)


def test_f_as_slope_of_the_landing_reads_the_staircases_trend_not_one_steps_flat(coulomb, sweep, monkeypatch):
    """f_a's landings form a staircase (its coin sticks and slips), so the slope that starts the
    landing line is a difference over ``SLOPE_SPAN_V``, several of its steps. On a staircase of 4 V
    steps with a trend of −10 µm/V the slope read at any end voltage lies within 25 % of the
    trend. Broken once (a 2 V difference, as before): on a step's flat it reads 0 (None: nothing is
    learnt), and across a riser −20 µm/V."""
    from deapull.control.env import CoinPushEnv
    from deapull.control.mpc_policy import X_UNIT_M, MPCConfig, MPCPolicy
    from deapull.control.plants import SurrogatePlant
    plant = SurrogatePlant(coulomb, coulomb.phi_of(sweep["C1"]), name="surrogate:C1")
    env = CoinPushEnv(plant, target_m=-0.4e-3)
    policy = MPCPolicy(coulomb, MPCConfig(horizon=10, iterations=4, inference=None), phi=plant.truth)
    policy.reset(env.task_spec())
    trend, step = -10e-6, 4.0

    def staircase(xi0, nu):
        V_end = float(nu.sum()) * policy.dv_max_V
        x = trend * step * np.floor(V_end / step) / X_UNIT_M
        return torch.full((1, nu.shape[1], 1), x, dtype=torch.float64)
    monkeypatch.setattr(policy, "_roll", staircase)
    shape = {"V_start": 0.0, "taper_V": 0.0}
    for V_f in (321.0, 350.5, 383.0, 399.0, 400.0):
        slope = policy._landing_slope(shape, V_f)
        assert slope is not None and abs(slope / trend - 1.0) < 0.25, (V_f, slope)


@pytest.mark.parametrize("sweep_on", [True, False])
def test_where_the_noise_cannot_be_averaged_down_the_push_sweeps_through_the_window(coulomb, sweep, monkeypatch,
                                                                                    sweep_on):
    """At σ = 1 mm the estimate cannot place the coin within a 10 µm window in time (``_unresolvable``).
    The sweep follows f_a open-loop inside the bias filter's gain band and moves even the
    farthest-travelling plant of the band at most 1.5 tolerances per step, so the coin crosses
    the window: 4/4 reached in 41–42 iterations at 10 V per step, f_a at 1.2 × the plant's μ_t.
    Broken once (``SWEEP`` off): the push trusts the noisy estimate, and the coin stops 10–90 µm
    short in 4 of 4 episodes (1 of 6 reached over 600 steps)."""
    from deapull.control import mpc_policy
    from deapull.control.env import CoinPushEnv
    from deapull.control.mpc_policy import MPCConfig, MPCPolicy
    from deapull.control.plants import SurrogatePlant
    from deapull.surrogate.phi import Phi
    from deapull.workflows.control import run_episode
    monkeypatch.setattr(mpc_policy, "SWEEP", sweep_on)
    plant = SurrogatePlant(coulomb, coulomb.phi_of(sweep["C1"]), name="surrogate:C1")
    truth = plant.truth
    env = CoinPushEnv(plant, target_m=-0.3e-3, terminate_on_success=False, max_steps=400, noise_std_m=1e-3,
                      dv_max_V=10.0)
    config = MPCConfig(horizon=10, iterations=4, inference=None, approach_m=1e-4, standoff_stds=2.0)
    phi = Phi(float(truth.mass_kg), float(truth.mu_b), 1.2 * float(truth.mu_t))
    policy = MPCPolicy(coulomb, config, phi=phi)
    rows = [run_episode(env, policy, seed=k, step_limit=300, hold_steps=10).row for k in range(4)]
    reached = sum(r["reached"] for r in rows)
    assert (reached == 4) if sweep_on else (reached == 0), [(r["iterations_to_target"], r["final_x_m"]) for r in rows]


def test_a_repeated_sweep_starts_from_the_gain_its_hold_measured_and_stops_nearer(coulomb, sweep, monkeypatch):
    """Across episodes of one task at σ = 1 mm, a sweep's hold averages where the coin stopped against
    f_a's open-loop end: the plant's gain to σ/(√n |x|), which the next episode's bias filter starts
    from. Its band is narrower, so the next sweep still crosses the window and holds once the
    least-travelling plant of that band is past it: on the fixture's surrogate at −0.2 mm the coin
    stops 249, 109 and 39 µm past in episodes 1–3 (on the shipped surrogates the later sweeps also
    slow down later: docs/control.md). Broken once (the filter not started from it): 249, 214 and
    248 µm."""
    from deapull.control.env import CoinPushEnv
    from deapull.control.mpc_policy import MPCConfig, MPCPolicy
    from deapull.control.plants import SurrogatePlant
    from deapull.surrogate.phi import Phi
    from deapull.workflows.control import run_episode
    plant = SurrogatePlant(coulomb, coulomb.phi_of(sweep["C1"]), name="surrogate:C1")
    truth = plant.truth
    env = CoinPushEnv(plant, target_m=-0.2e-3, terminate_on_success=False, max_steps=400, noise_std_m=1e-3,
                      dv_max_V=10.0)
    config = MPCConfig(horizon=10, iterations=4, inference=None, approach_m=1e-4, standoff_stds=2.0)
    policy = MPCPolicy(coulomb, config, phi=Phi(float(truth.mass_kg), float(truth.mu_b), 1.2 * float(truth.mu_t)))
    rows = [run_episode(env, policy, seed=k, step_limit=300, hold_steps=150).row for k in range(3)]
    (swept,) = policy.swept.values()
    assert swept["gain_var"] < (0.3 / 2) ** 2           # the hold at least halves the prior's std of 0.3
    assert all(r["reached"] for r in rows), rows
    past = [r["overshoot_m"] for r in rows]
    assert past[2] < past[1] < 0.6 * past[0], past


@pytest.mark.parametrize("kind", ["f-coulomb", "f-memory"])
def test_the_filter_propagates_f_as_own_velocity_not_the_gain_corrected_one(committed, sweep, kind):
    """The bias filter predicts each step as (1 + g) × f_a's step from the previous estimate; the
    velocity that step starts from is f_a's own (the plant's is (1 + g) times it, but f_a's
    inertia must not see it, or every step multiplies the model's velocity by 1 + g once more).
    Here the plant is f_a itself, pushed at 1 V per step from rest through its onset, and the filter
    holds g = 0.3 with observations that weigh nothing: the estimate then moves (1 + g) × the
    plant's travel.
    Broken once (the corrected velocity fed back): on the stand-in of fem:C3 the
    estimate raced 23 µm per step ahead of a coin moving 3.5, the plan saw the target coming and
    turned V down, and the push to −0.5 mm ended 24 µm past it."""
    from deapull.control.env import CoinPushEnv
    from deapull.control.mpc_policy import MPCConfig, MPCPolicy
    from deapull.control.plants import SurrogatePlant
    model = committed(kind)
    plant = SurrogatePlant(model, model.phi_of(sweep["C1"]), name="surrogate:C1")
    env = CoinPushEnv(plant, target_m=-0.6e-3, terminate_on_success=False, noise_std_m=1e-4, dv_max_V=1.0)
    _, info = env.reset(seed=0)
    policy = MPCPolicy(model, MPCConfig(inference=None), phi=plant.truth)
    policy.reset(env.task_spec())
    x0, V = info["x_m"], info["V_V"]
    policy._estimate(x0, V)
    policy.bias.reset(x0, gain=0.3, gain_var=1e-12, x_var=1e-16)
    policy.bias.q_g, policy.bias.r = 0.0, 1.0          # g fixed; the observations weigh nothing
    policy.previous = (x0, 0.0, V)
    while info["x_m"] > x0 - 150e-6:                    # the ramp, through the onset
        _, _, _, _, info = env.step(env.action_of(1.0))
        x, u = policy._estimate(info["x_m"], info["V_V"])
        policy.previous = (x, u, info["V_V"])
    travel = info["x_m"] - x0
    assert (x - x0) == pytest.approx(1.3 * travel, rel=0.05), (x - x0, travel)
