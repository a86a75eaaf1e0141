"""The MPC on an f-memory f_a (issue 24): the planning state ξ = (x, u, V, P, T) carries the
tip's memory, and the compiled step, Jacobians and iLQR (``native_mpc_memory.c``,
:class:`~deapull.control.native.NativeMemoryDynamics`) give the torch path's
(:class:`~deapull.control.dynamics.CoinDynamics` on ``TipMemoryAdapter.plan_step_memory``,
implicit gradients by autograd) to round-off.

Broken three times to watch them fail (then restored). (1) The sign of ∂T'/∂P flipped in the C
Jacobian (``dT_P = +dr_P / sl`` in native_mpc_memory.c): the Jacobian test failed ("Mismatched
elements: 980 / 8000 (12.2%), Greatest absolute difference: 60.7 at index (256, 4, 3)") and both
solver tests ("Mismatched elements: 10 / 18, Greatest absolute difference: 4.65e-05 at index
(0, 5)" in the cost history); the step tests passed. (2) CoinDynamics returning the memory
unscaled (``tail = list(memory.unbind(-1))`` in control/dynamics.py): all five failed (the
step: "640 / 1600 (40.0%), Greatest absolute difference: 1.76 at index (198, 4)"). (3) The
policy stepping its memory from the DEA at rest every step instead of from the memory it
tracked (``self.dynamics.state(x0, u0, V0)`` in MPCPolicy._estimate): both tracking tests failed
("Mismatched elements: 296 / 298 (99.3%), Greatest absolute difference: 0.00736 at index (44, 1)",
T in N).
"""
from __future__ import annotations

import shutil

import pytest
import torch

from deapull.control import mpc, native
from deapull.control.adapters import adapter
from tests.conftest import MODELS
from tests.control.jacobian_check import assert_jacobians_match_central_differences, assert_plans_match_torch

F64 = torch.float64
TRUTH_PHI = (1.36e-3, 0.2, 0.5)
DT, DV_MAX, V_MAX = 1e-3, 5.0, 400.0
pytestmark = pytest.mark.skipif(native.memory_library() is None, reason="no C compiler for the native MPC")


@pytest.fixture(scope="module")
def pair(committed):
    from deapull.control.dynamics import CoinDynamics
    from deapull.surrogate.phi import Phi
    model = committed("f-memory")
    phi = Phi(*TRUTH_PHI).to(dtype=F64)
    return (CoinDynamics(model, phi, DT, DV_MAX, V_MAX), native.native_dynamics(model, phi, DT, DV_MAX, V_MAX))


def states(slow, n=320, seed=0):
    """ξ of coins at rest and sliding (both ways) under a tip sticking and slipping (T within
    its bracket, P within a few ε_v Δt of X(V) − c T), every voltage, and the clipping edges."""
    g = torch.Generator().manual_seed(seed)
    xi = torch.stack([-0.6 * torch.rand(n, generator=g, dtype=F64),
                      2 * torch.rand(n, generator=g, dtype=F64) - 1.5,
                      4 * torch.rand(n, generator=g, dtype=F64),
                      torch.zeros(n, dtype=F64), torch.zeros(n, dtype=F64)], -1)
    xi[: n // 4, 1] = 0.0                          # at rest
    nu = 2 * torch.rand(n, 1, generator=g, dtype=F64) - 1
    xi[-4:, 2] = torch.tensor([0.0, 0.02, 3.98, 4.0], dtype=F64)
    nu[-4:, 0] = torch.tensor([-1.0, -1.0, 1.0, 1.0], dtype=F64)
    with torch.no_grad():
        X, fy0, c, b = slow.model.material_response(xi[:, 2] * 100.0)
    T = (2 * torch.rand(n, generator=g, dtype=F64) - 1) * 0.5 * fy0.abs()
    P = X - c * T + (2 * torch.rand(n, generator=g, dtype=F64) - 1) * 3e-6
    xi[:, 3], xi[:, 4] = P / slow.memory_units[0], T / slow.memory_units[1]
    return xi, nu


def test_the_planning_state_carries_the_memory(pair):
    """ξ is (x, u, V, P, T); one step of CoinDynamics is the model's own step with memory
    (V, P, T), and a rollout's memory is the model's rollout memory."""
    slow, _ = pair
    assert slow.n == 5 and slow.state(0.0, 0.0, 50.0).shape == (1, 5)
    model = slow.model
    x0 = slow.state(0.0, 0.0, 0.0)
    nu = torch.ones(1, 80, 1, dtype=F64)
    with torch.no_grad():
        path = mpc.rollout(slow, x0, nu)[0]
        s, memory = torch.zeros(1, 2, dtype=F64), model.rest_memory(torch.zeros(1, dtype=F64))   # at rest at 0 V
        for t in range(80):
            a = torch.tensor([[DV_MAX * (t + 1), DT]], dtype=F64)
            s, z, memory = model.step(s, a, memory, slow.phi)
    assert float(path[-1, 0]) < -0.1                      # the coin moved (mm) under the ramp
    torch.testing.assert_close(path[-1, 0] * 1e-3, s[0, 0], rtol=1e-12, atol=1e-15)
    torch.testing.assert_close(path[-1, 3:] * slow.memory_units, memory[0, 1:], rtol=1e-12, atol=1e-15)


def test_native_memory_step_is_the_torch_step(pair):
    slow, fast = pair
    xi, nu = states(slow)
    with torch.no_grad():
        expect = slow(xi, nu)
    got = fast(xi, nu)
    sliding = expect[:, 1] != 0
    assert 20 < int(sliding.sum()) < len(xi) - 20        # both regimes are tested
    torch.testing.assert_close(got, expect, rtol=1e-11, atol=1e-12)
    roll = mpc.rollout(slow, xi[:8], torch.ones(8, 15, 1, dtype=F64))
    torch.testing.assert_close(fast.rollout(xi[:8], torch.ones(8, 15, 1, dtype=F64)), roll, rtol=1e-11, atol=1e-12)


def test_native_memory_jacobians_are_autograds(pair):
    """∂ξ'/∂ξ and ∂ξ'/∂ν in C against autograd through the torch step (implicit gradients of
    the root), and both against central differences away from stick/slip switches."""
    slow, fast = pair
    xi, nu = states(slow, seed=1)
    A, B = fast.jacobian(xi, nu)
    A_ref, B_ref = mpc.linearize(slow, xi.unsqueeze(0), nu.unsqueeze(0))
    scale = float(A_ref.abs().max())
    torch.testing.assert_close(A, A_ref[0], rtol=1e-8, atol=1e-11 * scale)
    torch.testing.assert_close(B, B_ref[0], rtol=1e-8, atol=1e-11 * scale)
    assert float(A[:, 4, 3].abs().max()) > 1 and float(B[:, 0].abs().max()) > 1e-4   # P moves T, ν moves x
    assert_jacobians_match_central_differences(fast, xi, nu, A, B, DV_MAX / 100)


@pytest.mark.parametrize("final", [False, True])
def test_native_memory_solver_gives_the_torch_solvers_plans(pair, final):
    from deapull.control.dynamics import X_UNIT_M, coin_cost
    slow, fast = pair
    T = 10
    with torch.no_grad():
        path = fast.rollout(slow.state(0.0, 0.0, 0.0), torch.ones(1, 70, 1, dtype=F64))[0]
    moving = torch.nonzero(path[:, 1] != 0).flatten()
    x0 = path[moving[[0, len(moving) // 2, -1]]]
    target = float(path[-1, 0]) * X_UNIT_M * 1.05
    cost = coin_cost(target, memory=2)
    if not final:
        cost = mpc.QuadCost(cost.C, cost.c)
    assert_plans_match_torch(slow, fast, cost, x0, 5, T)


def _memory_episode(model, engine: str, steps: int = 150):
    """The f-memory MPC on a plant that is f_a itself (same φ, no noise, the DEA at rest at 0 V):
    per step the policy's tracked (P, T) (SI) and the plant's, and the actions."""
    from deapull.control.env import CoinPushEnv, policy_view
    from deapull.control.mpc_policy import MPCConfig, MPCPolicy
    from deapull.control.plants import SurrogatePlant
    from deapull.surrogate.phi import Phi
    truth = Phi(*TRUTH_PHI)
    plant = SurrogatePlant(model, truth)
    env = CoinPushEnv(plant, target_m=-0.2e-3, max_steps=steps, terminate_on_success=False)
    policy = MPCPolicy(model, MPCConfig(horizon=8, iterations=3, inference=None, engine=engine), phi=truth)
    obs, info = env.reset(seed=0)
    zero = torch.zeros(1, dtype=F64)
    with torch.no_grad():                    # the DEA at rest at 0 V, as the policy starts it
        plant._memory = torch.cat([zero.unsqueeze(0), adapter(plant.model).plan_start(zero)], -1)
    policy.reset(env.task_spec())
    tracked, truth_memory, actions = [], [], []
    for _ in range(steps):
        actions.append(policy.act(obs, policy_view(info)))
        if policy.memory is not None:
            tracked.append((policy.memory * policy.dynamics.memory_units).clone())
            truth_memory.append(plant._memory[0, 1:].clone())
        obs, _, terminated, truncated, info = env.step(env.action_of(actions[-1]))
        if terminated or truncated:
            break
    return torch.stack(tracked), torch.stack(truth_memory), actions, info, env


@pytest.mark.parametrize("engine", ["native", "torch"])
def test_the_policy_tracks_the_tips_memory_and_reaches_the_target(committed, engine):
    """The plant shows only x: the policy tracks P and T by its own model step. On a plant that
    is f_a, that is the plant's own memory at every step, through the stick, the slip and the
    hold, to the float32 precision of the observed x (the velocity the policy steps with is
    its finite difference: T agrees to ~2e-7 relative, P to ~1e-12 m); and the MPC brings the
    coin to the target."""
    model = committed("f-memory")
    tracked, memory, actions, info, env = _memory_episode(model, engine)
    assert float(memory[:, 1].abs().max()) > 1e-3                          # the tip carried friction (N)
    torch.testing.assert_close(tracked, memory, rtol=1e-5, atol=1e-11)
    assert env.reached_step is not None and abs(info["error_m"]) < 1e-5, (info["error_m"], info["V_V"])
    assert actions[0] == pytest.approx(DV_MAX) and min(actions[-10:]) < DV_MAX          # ramp, then the MPC


def test_a_plan_that_leaves_the_coin_standing_short_of_the_target_creeps(committed, monkeypatch):
    """``UNSTALL``: on a memoryless plant, in a push to −0.30 mm, back to −0.25 mm and on to
    −0.30 mm, the f-memory MPC's solved plans can hold V with the coin standing (its model's
    tip must reload its friction first, late in the horizon or beyond it); the policy creeps
    instead, and with horizons of 6, 8 and 20 steps the coin reaches every target, each after
    the first within 20 steps. Without the rule one of the horizons stalls for good (measured:
    at 8 steps the coin never reached the first target in 1,200 steps; at 6 and 20: 60;5;6 and
    60;6;5 steps). Broken once (the creep replaced by ``dV = 0.0`` in MPCPolicy.act): the
    first assertion failed. Re-centring is off here: it moves the coin
    during the holds, which would hide the rule."""
    from deapull.control import mpc_policy
    from deapull.control.env import CoinPushEnv
    from deapull.control.mpc_policy import MPCConfig, MPCPolicy
    from deapull.control.plants import SurrogatePlant
    from deapull.surrogate.phi import Phi
    from deapull.workflows.control import run_episode
    phi = Phi(*TRUTH_PHI)
    plant = SurrogatePlant(committed("f-coulomb"), phi)
    setpoints = (-0.3e-3, -0.25e-3, -0.3e-3)
    monkeypatch.setattr(mpc_policy, "RECENTRE_STDS", 0.0)
    steps = {}
    for unstall in (True, False):
        monkeypatch.setattr(mpc_policy, "UNSTALL", unstall)
        for horizon in (6, 8, 20):
            env = CoinPushEnv(plant, target_m=setpoints[0], terminate_on_success=False, max_steps=4000)
            policy = MPCPolicy(committed("f-memory"), MPCConfig(inference=None, horizon=horizon), phi=phi)
            row = run_episode(env, policy, seed=0, step_limit=1200, hold_steps=50, setpoints_m=setpoints).row
            steps[unstall, horizon] = [None if s == "None" else int(s) for s in row["iterations_per_setpoint"].split(";")]
    # reached, not settled: the hold at the pull-back's −0.25 mm is the f-memory model's release
    assert all(len(steps[True, h]) == 3 and None not in steps[True, h] and max(steps[True, h][1:]) < 20
               for h in (6, 8, 20)), steps
    # without the rule the coin stands short of a target for good, or for 40 steps or more
    assert any(s is None or s > 40 for h in (6, 8, 20) for s in steps[False, h]), steps


def test_the_cli_plans_and_infers_with_an_f_memory_model(committed, sweep_dir, fs1_dir, tmp_path):
    """``deapull control --mpc-model <f-memory>``: by default the MPC infers φ online with the
    f-memory f_a (its buffer carries the tip's memory) and the CSV records the estimate, inside
    the physical box; with ``mpc_phi = "prior"`` and ``--phi-prior coins`` the compiled f-memory MPC plans
    at the prior's median and records none. Broken once (the ``infer`` capability taken off
    f-memory): the default run exited 2 ("assert 2 == 0")."""
    import csv

    from deapull.control.inference import BOUNDS
    from deapull.workflows.cli import main
    folder = shutil.copytree(MODELS / "f-memory", tmp_path / "fmem")
    argv = ["control", "--policy", "mpc", "--plant", "surrogate:C1", "--data", str(sweep_dir), "--plant-model",
            str(fs1_dir), "--mpc-model", str(folder), "--no-progress",
            "--episodes", "1", "--noise", "0", "--target-mm", "-0.2", "--max-steps", "300", "--hold", "20"]
    for name, extra in (("infer", []), ("fixed", ["--set", "control.mpc_phi='prior'", "--phi-prior", "coins"])):
        assert main(argv + ["--out", str(tmp_path / name), *extra]) == 0
        with open(tmp_path / name / "control.csv", newline="") as f:
            (row,) = list(csv.DictReader(f))
        assert row["reached"] == "True", row
        if name == "fixed":
            assert row["inferred_mass_kg"] == "", row
        else:
            for field, (lo, hi) in BOUNDS.items():
                if field != "v_threshold_V":
                    assert lo <= float(row[f"inferred_{field}"]) <= hi, (field, row)
