"""The plants and the env: gymnasium's and stable-baselines3's checkers, success on the true
state, the voltage limits, seeded noise, the reward, the surrogate plant against the
surrogate's own rollout, and (``fem``) the FEM plant against the FEM's own stepping."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from deapull.control.env import POLICY_INFO, CoinPushEnv, policy_view
from deapull.errors import InputError
from tests.control.conftest import FIXTURE_TARGET_M, ParkedPlant, RatchetPlant
from tests.conftest import SHARP, TINY_MESH


@pytest.mark.parametrize("noise", [0.0, 1e-3])
def test_env_passes_gymnasium_and_sb3_checkers_without_warnings(surrogate_plant, noise):
    from gymnasium.utils.env_checker import check_env as gymnasium_check
    from stable_baselines3.common.env_checker import check_env as sb3_check
    env = CoinPushEnv(surrogate_plant, noise_std_m=noise, max_steps=20)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        gymnasium_check(env, skip_render_check=True)
        sb3_check(env, warn=True)
    assert env.action_space.shape == (1,) and float(env.action_space.low[0]) == -1.0
    assert env.observation_space.shape == (2,)


def test_success_is_judged_on_the_true_state_not_on_the_noisy_observation():
    """A coin parked 2 tolerances from the target, observed with noise of one tolerance:
    a third of the observations fall inside the window, yet the episode never succeeds;
    parked inside the window, it succeeds at the first step under the paper's 1 mm noise."""
    target, tol = -1e-3, 1e-5
    env = CoinPushEnv(ParkedPlant(target + 2 * tol), noise_std_m=tol, max_steps=300)
    env.reset(seed=3)
    inside = 0
    for _ in range(300):
        obs, _, terminated, truncated, info = env.step(env.action_of(0.0))
        inside += abs(env.position_of(obs) - target) < tol
        assert not info["success"] and not terminated
    assert truncated and inside > 30
    env = CoinPushEnv(ParkedPlant(target + 0.5 * tol), noise_std_m=1e-3)
    env.reset(seed=3)
    obs, _, terminated, _, info = env.step(env.action_of(0.0))
    assert terminated and info["success"] and info["reached_step"] == 1
    assert abs(env.position_of(obs) - target) > 10 * tol       # the observation was far off


def test_voltage_moves_by_the_action_times_the_limit_and_stays_in_range():
    env = CoinPushEnv(RatchetPlant(), dv_max_V=5.0, v_max_V=400.0)
    obs, info = env.reset(seed=0)
    assert env.voltage_of(obs) == 0.0 and info["V_V"] == 0.0
    _, _, _, _, info = env.step(np.array([0.5], dtype=np.float32))
    assert info["V_V"] == pytest.approx(2.5) and info["dV_V"] == pytest.approx(2.5)
    _, _, _, _, info = env.step(np.array([7.0], dtype=np.float32))          # clipped to +1: +5 V
    assert info["V_V"] == pytest.approx(7.5)
    _, _, _, _, info = env.step(env.action_of(-100.0))                     # -5 V at most
    assert info["V_V"] == pytest.approx(2.5)
    _, _, _, _, info = env.step(env.action_of(-5.0))                       # never below 0 V
    assert info["V_V"] == 0.0 and info["dV_V"] == pytest.approx(-2.5)
    for _ in range(100):
        obs, _, _, _, info = env.step(env.action_of(5.0))
    assert info["V_V"] == 400.0 and env.plant.V == 400.0 and env.voltage_of(obs) == pytest.approx(400.0)
    assert env.action_of(2.0)[0] == pytest.approx(0.4) and env.action_of(2.0).dtype == np.float32
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([np.nan], dtype=np.float32))


def test_noise_is_seeded_gaussian_on_x_only():
    x = -0.5e-3
    env = CoinPushEnv(ParkedPlant(x), noise_std_m=1e-4)

    def observations(seed):
        env.reset(seed=seed)
        return np.array([env.step(env.action_of(0.1))[0] for _ in range(2000)])

    a, b, c = observations(1), observations(1), observations(2)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a[:, 0], c[:, 0])
    noise = a[:, 0] * 1e-3 - x
    assert abs(noise.mean()) < 1e-5 and noise.std() == pytest.approx(1e-4, rel=0.05)
    np.testing.assert_allclose(a[:, 1], 0.1 * np.arange(1, 2001) / 400, rtol=1e-5)   # V exact
    quiet = CoinPushEnv(ParkedPlant(x), noise_std_m=0.0)
    quiet.reset(seed=1)
    assert quiet.position_of(quiet.step(quiet.action_of(0.0))[0]) == pytest.approx(x, rel=1e-6)


def test_reward_is_scaled_distance_and_voltage_change_on_the_true_state():
    env = CoinPushEnv(ParkedPlant(-0.75e-3), noise_std_m=1e-3, dv_weight=0.01, dv_max_V=5.0)
    env.reset(seed=0)
    _, reward, _, _, _ = env.step(env.action_of(2.5))
    assert reward == pytest.approx(-0.25 - 0.01 * 0.5 ** 2)


@pytest.mark.parametrize("x, inside", [(-1.004e-3, True), (-0.985e-3, False)])
def test_the_success_bonus_is_paid_inside_the_window_only(x, inside):
    """b = 1 is added to the reward at a step whose true x is inside ±0.01 mm, not outside;
    0 (the paper's reward) by default."""
    rewards = []
    for bonus in (0.0, 1.0):
        env = CoinPushEnv(ParkedPlant(x), noise_std_m=1e-3, success_bonus=bonus, terminate_on_success=False)
        env.reset(seed=0)
        rewards.append(env.step(env.action_of(0.0))[1])
    assert rewards[0] == pytest.approx(-abs(x + 1e-3) / 1e-3)
    assert rewards[1] - rewards[0] == pytest.approx(1.0 if inside else 0.0)


def test_truncation_at_the_step_limit_and_termination_only_when_asked():
    env = CoinPushEnv(RatchetPlant(), max_steps=5)
    env.reset(seed=0)
    flags = [env.step(env.action_of(1.0))[2:4] for _ in range(5)]
    assert flags == [(False, False)] * 4 + [(False, True)]
    target = -RatchetPlant().gain * 10.0            # reached 10 V above the onset
    for terminate in (True, False):
        env = CoinPushEnv(RatchetPlant(), target_m=target, terminate_on_success=terminate, start_voltage_V=150.0)
        env.reset(seed=0)
        for _ in range(2):
            _, _, terminated, _, info = env.step(env.action_of(5.0))
        assert info["success"] and info["reached_step"] == 2 and terminated == terminate


def test_policies_see_no_true_state():
    env = CoinPushEnv(RatchetPlant())
    _, info = env.reset(seed=0)
    assert {"x_m", "u_m_s", "error_m", "success"} <= set(info)
    assert set(policy_view(info)) == set(POLICY_INFO) and not {"x_m", "u_m_s", "error_m"} & set(POLICY_INFO)


@pytest.mark.parametrize("kwargs, word", [
    ({"noise_std_m": -1e-4}, "noise_std_m"), ({"noise_std_m": float("nan")}, "noise_std_m"),
    ({"target_m": 1e-3}, "target_m"), ({"dv_max_V": 0.0}, "dv_max_V"), ({"max_steps": 0}, "max_steps"),
    ({"tolerance_m": -1.0}, "tolerance_m"), ({"start_voltage_V": (300.0, 100.0)}, "start_voltage_V"),
    ({"success_bonus": -1.0}, "success_bonus"), ({"success_bonus": float("nan")}, "success_bonus"),
])
def test_bad_env_arguments_are_refused_by_name(kwargs, word):
    with pytest.raises(InputError, match=word):
        CoinPushEnv(RatchetPlant(), **kwargs)


def test_start_voltage_is_reached_by_a_ramp_and_drawn_from_the_seeded_range():
    """reset ramps the plant from 0 V to the start voltage at 0.5 V per step, so the coin
    starts where that ramp left it (ratchet: 5 µm per volt above 150 V)."""
    env = CoinPushEnv(RatchetPlant(), start_voltage_V=(0.0, 300.0))
    starts = {}
    for seed in range(20):
        _, info = env.reset(seed=seed)
        starts[info["V_V"]] = info["x_m"]
        assert env.plant.V == info["V_V"] and info["step"] == 0
    assert len(starts) == 20 and min(starts) >= 0 and max(starts) <= 300
    for V0, x in starts.items():
        assert x == pytest.approx(-5e-6 * max(V0 - 150.0, 0.0), abs=1e-12)
    assert env.reset(seed=4)[1]["V_V"] == env.reset(seed=4)[1]["V_V"]


# --- the surrogate plant -------------------------------------------------------------------

def test_surrogate_plant_steps_as_the_surrogates_own_rollout(surrogate_plant, fs1_model, sweep):
    """A 0 → 400 V ramp at 0.5 V per step through the plant = the same actions through
    deapull.surrogate.rollout (torch engine, float32): the plant carries the model's memory
    from step to step and applies V at the end of each step."""
    import torch

    from deapull.surrogate.rollout import OutOfRangeWarning, rollout
    V = np.minimum(0.5 * np.arange(1, 1001), 400.0)
    surrogate_plant.reset()
    states = np.array([surrogate_plant.step(v) for v in V])
    assert surrogate_plant.t == pytest.approx(1.0) and surrogate_plant.V == 400.0
    actions = torch.tensor(np.stack([V, np.full_like(V, 1e-3)], axis=1), dtype=torch.float32)
    with torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)     # 400 V held: beyond the fixture's last speed
        reference = rollout(fs1_model, fs1_model.phi_of(sweep["C1"]), torch.zeros(2), actions, engine="torch")
    reference = reference.states[0, 1:]
    travel = np.abs(states[:, 0]).max()
    assert travel > 0.4e-3                                      # the coin slides
    np.testing.assert_allclose(states[:, 0], reference[:, 0].double().numpy(), atol=1e-4 * travel)


def test_surrogate_plant_on_the_fems_ramp_reaches_the_target_where_the_fem_did(surrogate_plant, sweep):
    """+0.5 V per step (the FEM dataset's ramp: 0.56 V per step) takes the plant's coin
    into the window at the voltage where the FEM's coin entered it (measured: 275.5 V
    against the FEM's 278 V)."""
    env = CoinPushEnv(surrogate_plant, target_m=FIXTURE_TARGET_M)
    env.reset(seed=0)
    for _ in range(1000):
        *_, terminated, _, info = env.step(env.action_of(0.5))
        if terminated:
            break
    assert terminated and abs(info["x_m"] - FIXTURE_TARGET_M) < 1e-5
    fem = sweep["C1"]
    entry = fem.V[np.argmax(fem.x <= FIXTURE_TARGET_M + 1e-5)]
    assert info["V_V"] == pytest.approx(entry, rel=0.03)


# --- the FEM plant (dolfinx) ---------------------------------------------------------------

@pytest.mark.fem
def test_fem_plant_episode_moves_the_coin_as_the_fems_own_stepping(tmp_path):
    """On a tiny mesh: the env + FEM plant, started at 150 V (the env's ramp of 0.5 V per
    step from 0 V), then driven by +3 V per step for 14 steps, against the FEM's own
    start() / advance(V(t), 1 ms) with V(t) the scene's table protocol through the same
    points: the same coin positions to round-off, and the coin slides toward −x. The next reset
    reuses the placement (broken once, the plant without its placement cache: 'solved')."""
    from deapull import scene as scenes
    from deapull.control.plants import FEMPlant
    from deapull.control.policies import HeuristicPolicy
    from deapull.fem_solver.stepping import scene_protocol
    from deapull.workflows.control import run_episode
    V0, dV, n = 150.0, 3.0, 14
    ramp = int(V0 / 0.5)                       # steps of the env's start ramp
    table = ("load.protocol='table'", f"load.table_t_s=[0, {ramp * 1e-3}, {(ramp + n) * 1e-3}]",
             f"load.table_V=[0, {V0}, {V0 + n * dV}]", f"load.end_time_s={(ramp + n) * 1e-3}")
    scene = scenes.load("coin_pull", setup="C1", overrides=(*SHARP, *TINY_MESH, *table))
    plant = FEMPlant(scene, work_dir=tmp_path, name="fem:C1")
    env = CoinPushEnv(plant, dv_max_V=dV, start_voltage_V=V0, max_steps=n, terminate_on_success=False)
    episode = run_episode(env, HeuristicPolicy(step_V=dV), seed=0, step_limit=n, hold_steps=0)
    assert episode.row["status"] == "ok" and episode.row["steps_run"] == n
    np.testing.assert_allclose(episode.V_V, V0 + dV * np.arange(n + 1), rtol=1e-12)
    assert plant.t == pytest.approx((ramp + n) * 1e-3)

    protocol = scene_protocol(scene)
    own = plant.simulation.stepper(progress=False)
    records = [own.start(protocol(0.0))] + [own.advance(protocol(k * 1e-3), 1e-3) for k in range(1, ramp + n + 1)]
    x_own = np.array([r.x for r in records[ramp:]])
    assert x_own[-1] < -2e-5                                      # it slid (measured: -0.066 mm)
    np.testing.assert_allclose(episode.x_m, x_own, rtol=0, atol=1e-9 * abs(x_own[-1]))
    assert plant.truth.mass_kg == pytest.approx(plant.mass_kg) and plant.truth.mu_t == scene.coin.mu_t
    # the next episode starts from the first one's placement (kept in work_dir), to the Newton tolerance
    placed = plant.records[0] if plant.records[0].t == 0.0 else None
    assert placed is not None and plant.stepper.placement == "solved"
    plant.reset()
    assert plant.stepper.placement == "reused"
    assert plant.records[0].Fy == pytest.approx(placed.Fy, abs=scene.solver.newton_atol)
