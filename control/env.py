"""The coin-push task as a gymnasium environment over a plant (:mod:`deapull.control.plants`).

The task (paper §VI-B): push the coin from x = 0 to x^T = −1 mm, steps of Δt = 1 ms,
V ∈ [0, 400] V. Judged on the **true** state: an episode succeeds at the first step with
|x − x^T| < 0.01 mm. The observation carries Gaussian noise of std ``noise_std_m`` on x,
drawn from the env's seeded generator (``reset(seed=...)``): the paper's 1e-3 m equals the
whole target, so success judged on the observation would be luck.

**Action** (Box [−1, 1], float32): the voltage change ΔV = action · ΔV_max, then
V ← clip(V + ΔV, 0, V_max). **The per-step limit ΔV_max** (default :data:`DV_MAX_V` =
5 V per 1 ms step, i.e. 5 kV/s) is the same for every policy: the quasi-static DEA
follows its voltage at once, so iterations to target mean nothing without it. 5 V is ten
times the heuristic's +0.5 V step, so the limit never binds the paper's PD or ramp and
only the fast policies (MPC, SAC) meet it; from 0 V it reaches the ~372 V that puts the
coin of C1 at −1 mm in 75 steps, which leaves room under the 100-iteration MPC goal.
Beyond ~2 V per step a faster ramp buys less travel: the coin's travel depends on the
ramp rate (the tip drags it through the FEM's rate-regularised friction, ε_v = 0.1 mm/s).
On f_s,1 (shipped mesh) a ramp to 372 V held for 50 steps leaves the coin at −1.02, −1.03,
−1.02 mm at 0.5, 1, 2 V per step, but −0.91 mm at 5 V and −0.56 mm at 10 V (the coin's
inertia lets the tip slip over it), and −0.82 mm at 0.1 V, −0.27 mm at 0.02 V per step
(the tip's slip rate falls under ε_v and its drag under the ground's friction).

**Observation** (float32, :data:`OBSERVATION`): (x̃/s, V/V_max) with s = 1 mm, x̃ = x + σ ε
the noisy coin position (ε ~ N(0, 1)), V the applied voltage (exact: the controller sets
it). The velocity is not observed (a difference of noisy positions; a policy that wants it
keeps the previous observation). :meth:`CoinPushEnv.position_of` and
:meth:`CoinPushEnv.voltage_of` read it back in SI units.

**Reward** (scaled): r = −|x − x^T|/s − w (ΔV/ΔV_max)² + b·[|x − x^T| < tolerance], on the
true state (the simulated env knows it; the noise only changes what the policy sees),
w = :data:`DV_WEIGHT`, b = ``success_bonus`` (0, the paper's reward, unless set). An
episode ends (``terminated``) at success unless ``terminate_on_success=False`` (the
harness keeps stepping to see whether the coin stays), and is truncated after
``max_steps``.

``info`` holds the step, time, voltage, ΔV and the current target (:data:`POLICY_INFO`,
what a policy may read), the true state and error, ``success`` and ``reached_step`` (first
success of the current target).

**Setpoints.** :meth:`CoinPushEnv.set_target` moves the target during an episode (the
multi-setpoint task: push to −0.5 mm, on to −1.0 mm, pull back to −0.7 mm); success and
``reached_step`` then refer to the new target. A policy reads the target from ``info``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from deapull.errors import InputError

#: target coin position x^T (m) and the success window |x − x^T| < tolerance (m)
TARGET_M = -1e-3
TOLERANCE_M = 1e-5
#: voltage range (V) and the per-step limit of |ΔV| (V per Δt = 1 ms) of every policy
V_MAX_V = 400.0
DV_MAX_V = 5.0
#: default step limit (4 s of plant time; the paper's PD took ~1,500 iterations)
MAX_STEPS = 4000
#: length scale of observations and rewards (m)
POSITION_SCALE_M = 1e-3
#: weight of the scaled voltage change in the reward
DV_WEIGHT = 0.01
#: observations beyond ±this (scaled) are clipped (noisy positions of ±100 mm)
OBS_BOUND = 100.0
#: voltage step (V) of the ramp from 0 V to an episode's start voltage (the FEM data's rate)
START_RAMP_V = 0.5
#: info keys a policy may read (the rest is the true state, for reporting)
POLICY_INFO = ("step", "t_s", "V_V", "dV_V", "target_m")


def policy_view(info: dict) -> dict:
    """The part of the env's ``info`` that a policy may see (:data:`POLICY_INFO`)."""
    return {k: info[k] for k in POLICY_INFO}


@dataclass(frozen=True)
class TaskSpec:
    """All that a policy may know of the task before an episode: numbers, never the env or the
    plant (so a policy cannot read the true state). :meth:`CoinPushEnv.task_spec` makes it.

    Attributes
    ----------
    target_m, tolerance_m : target x^T and success window (m)
    dt_s : the plant's step (s)
    dv_max_V, v_max_V : per-step limit of |ΔV| and largest voltage (V)
    noise_std_m : standard deviation of the observation noise (m; 0: exact observations)
    observation : names of the observation's entries
    """
    target_m: float
    tolerance_m: float
    dt_s: float
    dv_max_V: float
    v_max_V: float
    noise_std_m: float
    observation: tuple

    @staticmethod
    def position_of(obs) -> float:
        """The observed (noisy) coin position x̃ (m) in an observation."""
        return float(obs[0]) * POSITION_SCALE_M

    def voltage_of(self, obs) -> float:
        """The applied voltage (V) in an observation."""
        return float(obs[1]) * self.v_max_V


def _positive(name: str, value: float, allow_zero: bool = False) -> float:
    value = float(value)
    ok = math.isfinite(value) and (value >= 0 if allow_zero else value > 0)
    if not ok:
        raise InputError(f"{name} = {value!r}: must be a finite number {'>= 0' if allow_zero else '> 0'}")
    return value


class CoinPushEnv(gym.Env):
    """Push the coin to x^T within the tolerance, on the true state of ``plant``.

    Parameters
    ----------
    plant : deapull.control.plants.Plant
    target_m : float
        x^T (m), < 0: the coin moves toward −x.
    tolerance_m : float
        Success window (m) on the true |x − x^T|.
    dv_max_V : float
        Largest |ΔV| per step (V).
    v_max_V : float
        Largest voltage (V).
    max_steps : int
        Steps before truncation.
    noise_std_m : float
        Std of the Gaussian noise on the observed x (m), >= 0.
    terminate_on_success : bool
        End the episode at the first success (the paper's episode).
    dv_weight : float
        Weight w of (ΔV/ΔV_max)² in the reward.
    success_bonus : float
        b, added to the reward at each step inside the window (0: the paper's reward).
    start_voltage_V : float or (float, float)
        The voltage an episode starts from: ``reset`` ramps the plant from 0 V to it at
        :data:`START_RAMP_V` per step (the coin moves as it would under that ramp; those
        steps are not the episode's). A range draws it uniformly from the env's generator
        (exploration in SAC training: starts on the way to the target); 0 to evaluate.
    """

    metadata = {"render_modes": []}
    OBSERVATION = ("x_noisy / 1 mm", "V / V_max")

    def __init__(self, plant, target_m: float = TARGET_M, tolerance_m: float = TOLERANCE_M,
                 dv_max_V: float = DV_MAX_V, v_max_V: float = V_MAX_V, max_steps: int = MAX_STEPS,
                 noise_std_m: float = 0.0, terminate_on_success: bool = True, dv_weight: float = DV_WEIGHT,
                 start_voltage_V=0.0, success_bonus: float = 0.0):
        super().__init__()
        self.plant = plant
        self.target_m = float(target_m)
        if not (math.isfinite(self.target_m) and self.target_m < 0):
            raise InputError(f"target_m = {target_m!r}: must be a finite number < 0 (the coin moves toward -x)")
        self.tolerance_m = _positive("tolerance_m", tolerance_m)
        self.dv_max_V = _positive("dv_max_V", dv_max_V)
        self.v_max_V = _positive("v_max_V", v_max_V)
        self.noise_std_m = _positive("noise_std_m", noise_std_m, allow_zero=True)
        self.dv_weight = _positive("dv_weight", dv_weight, allow_zero=True)
        self.success_bonus = _positive("success_bonus", success_bonus, allow_zero=True)
        if int(max_steps) != max_steps or max_steps < 1:
            raise InputError(f"max_steps = {max_steps!r}: must be an integer >= 1")
        self.max_steps = int(max_steps)
        lo, hi = (start_voltage_V, start_voltage_V) if np.isscalar(start_voltage_V) else start_voltage_V
        lo = _positive("start_voltage_V", lo, allow_zero=True)
        hi = _positive("start_voltage_V", hi, allow_zero=True)
        if not lo <= hi <= self.v_max_V:
            raise InputError(f"start_voltage_V = {start_voltage_V!r}: needs low <= high <= v_max_V = {self.v_max_V}")
        self.start_voltage_V = (lo, hi)
        self.terminate_on_success = bool(terminate_on_success)
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)
        self.observation_space = gym.spaces.Box(np.array([-OBS_BOUND, 0.0], dtype=np.float32),
                                                np.array([OBS_BOUND, 1.0], dtype=np.float32), dtype=np.float32)
        self.steps, self.V, self.reached_step = 0, 0.0, None
        self.state = np.zeros(2)

    # --- reading observations and writing actions ---------------------------------------

    def set_target(self, target_m: float) -> None:
        """Move the target to ``target_m`` (m, < 0) from the next step on; ``reached_step``
        starts afresh."""
        target_m = float(target_m)
        if not (math.isfinite(target_m) and target_m < 0):
            raise InputError(f"target_m = {target_m!r}: must be a finite number < 0 (the coin moves toward -x)")
        self.target_m, self.reached_step = target_m, None

    def task_spec(self) -> TaskSpec:
        """What a policy may know of this task (:class:`TaskSpec`): the only thing
        ``Policy.reset`` gets."""
        return TaskSpec(target_m=self.target_m, tolerance_m=self.tolerance_m, dt_s=float(self.plant.dt),
                        dv_max_V=self.dv_max_V, v_max_V=self.v_max_V, noise_std_m=self.noise_std_m,
                        observation=tuple(self.OBSERVATION))

    position_of = staticmethod(TaskSpec.position_of)

    def voltage_of(self, obs) -> float:
        """The applied voltage (V) in an observation."""
        return float(obs[1]) * self.v_max_V

    def action_of(self, dV_V: float) -> np.ndarray:
        """The action that asks for the voltage change ``dV_V`` (V), clipped to ±ΔV_max."""
        return np.array([np.clip(dV_V / self.dv_max_V, -1.0, 1.0)], dtype=np.float32)

    # --- gymnasium API ----------------------------------------------------------------

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        lo, hi = self.start_voltage_V
        V0 = float(self.np_random.uniform(lo, hi)) if hi > lo else lo
        self.state = self.plant.reset(seed=int(self.np_random.integers(2**31)))
        ramp = np.arange(1, math.ceil(V0 / START_RAMP_V) + 1) * START_RAMP_V
        for V in np.minimum(ramp, V0):
            self.state = self.plant.step(float(V))
        self.steps, self.V, self.reached_step = 0, V0, None
        return self._observe(), self._info(0.0)

    def step(self, action):
        a = float(np.clip(np.asarray(action, dtype=np.float64).reshape(-1)[0], -1.0, 1.0))
        if not math.isfinite(a):
            raise ValueError(f"action {action!r}: not a finite number")
        V_new = float(np.clip(self.V + a * self.dv_max_V, 0.0, self.v_max_V))
        dV, self.V = V_new - self.V, V_new
        self.state = self.plant.step(V_new)
        self.steps += 1
        error = self.state[0] - self.target_m
        success = bool(abs(error) < self.tolerance_m)
        if success and self.reached_step is None:
            self.reached_step = self.steps
        reward = (-abs(error) / POSITION_SCALE_M - self.dv_weight * (dV / self.dv_max_V) ** 2
                  + self.success_bonus * success)
        terminated = success and self.terminate_on_success
        truncated = not terminated and self.steps >= self.max_steps
        return self._observe(), float(reward), terminated, truncated, self._info(dV)

    def _observe(self) -> np.ndarray:
        x_noisy = self.state[0] + (self.noise_std_m * self.np_random.standard_normal() if self.noise_std_m else 0.0)
        obs = np.array([x_noisy / POSITION_SCALE_M, self.V / self.v_max_V], dtype=np.float64)
        return np.clip(obs, self.observation_space.low, self.observation_space.high).astype(np.float32)

    def _info(self, dV: float) -> dict:
        x, u = float(self.state[0]), float(self.state[1])
        return {"step": self.steps, "t_s": self.plant.t, "V_V": self.V, "dV_V": dV, "target_m": self.target_m,
                "x_m": x, "u_m_s": u,
                "error_m": x - self.target_m, "success": bool(abs(x - self.target_m) < self.tolerance_m),
                "reached_step": self.reached_step}
