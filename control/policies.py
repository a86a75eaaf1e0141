"""Policies: one interface for every controller, and the paper's three baselines.

A policy sees what a controller of the real actuator would see — the env's observation
(the noisy coin position and the applied voltage, :mod:`deapull.control.env`) and the
``info`` keys of :data:`deapull.control.env.POLICY_INFO` (step, time, voltage) — and
returns the voltage **change** ΔV (V) for the next step of Δt = 1 ms. The env clips ΔV to
its per-step limit ±ΔV_max and the voltage to [0, V_max]; every policy runs under the same
limit. The true state never reaches a policy.

* :class:`Policy` — the interface (``name``, ``reset(env)``, ``act(obs, info) -> ΔV``,
  ``inferred()``); the MPC (:mod:`deapull.control.mpc_policy`) implements it too.
* :class:`PDPolicy` — the paper's PD, K_p = −0.5, K_d = 5, on the error in millimetres.
* :class:`HeuristicPolicy` — the paper's ramp, +0.5 V per step.
* :class:`SACPolicy` — soft actor-critic (stable-baselines3; the paper's 2 × 256 networks,
  τ = 0.005), trained on a surrogate env by :func:`train_sac`, saved and loaded.
"""
from __future__ import annotations

import json
import time
from abc import ABC, abstractmethod
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from deapull.control.filters import FILTERS, ConstantVelocityKalman
from deapull.errors import InputError
from deapull.io import atomic_write, write_json


class Policy(ABC):
    """A controller of the coin-push env: ΔV (V) from the observation.

    Attributes
    ----------
    name : str
        Short name for tables and plots (``pd``, ``heur``, ``sac``, ``mpc``).

    The harness (:func:`deapull.control.harness.run_episode`) calls ``reset(spec)`` after
    every ``env.reset``, then ``act`` once per step; the wall time of ``act`` is the
    policy's time per iteration. A policy sees the task's constants and the observations
    only, never the env or the plant (tests/control/test_policies.py checks it).
    """

    name: str = ""

    def reset(self, spec) -> None:
        """Start an episode of the task ``spec`` (a :class:`~deapull.control.env.TaskSpec`:
        target, Δt, ΔV_max, V_max, noise) and clear any memory."""

    @abstractmethod
    def act(self, obs: np.ndarray, info: dict) -> float:
        """The voltage change ΔV (V) to apply over the next step.

        Parameters
        ----------
        obs : numpy.ndarray
            The env's observation (:data:`deapull.control.env.OBSERVATION`).
        info : dict
            The keys of :data:`deapull.control.env.POLICY_INFO` only.
        """

    def inferred(self) -> dict:
        """The policy's current estimate of the coin's parameters φ, by field of
        :class:`~deapull.surrogate.phi.Phi` (SI units); empty for policies that infer none."""
        return {}


class PDPolicy(Policy):
    """The paper's PD controller on the voltage increment.

    With the error e_t = (x^T − x̃_t) / 1 mm (millimetres; x̃ the noisy observed position;
    e < 0 while the coin is short of the target, since it travels toward −x)::

        ΔV_t [V] = K_p e_t + K_d (e_t − e_{t−1}),   K_p = −0.5 V/mm,  K_d = 5 V/mm,

    e_{t−1} = e_t at the first step. At the start (e = −1 mm) the PD raises the voltage by
    0.5 V per step, as the heuristic does, and slows down in proportion to the remaining
    distance: ΔV is an increment, so K_p acts as the integral gain of V and K_d as its
    proportional gain. The derivative term is on the per-step difference of the noisy
    error, so observation noise of std σ adds ≈ K_d √2 σ/1 mm to each ΔV.

    Near the target ΔV shrinks with the error, and below ~0.01 V per step the tip moves too
    slowly to drag the coin (its slip rate falls under the friction's regularisation, see
    :mod:`deapull.control.env`): without noise this PD stalls 0.012 mm short of x^T, on
    f_s,1 and on the FEM of C1 alike (measured); a little noise dithers it in.

    With ``filter="kf"`` (name ``pd+kf``) the error is taken on the estimate of a
    constant-velocity Kalman filter (:class:`~deapull.control.filters.ConstantVelocityKalman`,
    acceleration noise ``accel_std`` m/s²) instead of on x̃.
    """

    name = "pd"

    def __init__(self, kp_V_per_mm: float = -0.5, kd_V_per_mm: float = 5.0, filter: str = "none",
                 accel_std: float = 0.05):
        if filter not in FILTERS:
            raise InputError(f"PD filter {filter!r}: choose one of {', '.join(FILTERS)}")
        self.kp, self.kd = float(kp_V_per_mm), float(kd_V_per_mm)
        self.filter, self.accel_std = filter, float(accel_std)
        self.name = "pd" if filter == "none" else f"pd+{filter}"
        self.target_m, self.previous = float("nan"), None

    def reset(self, spec) -> None:
        self.target_m, self.previous, self.spec = spec.target_m, None, spec
        self.kalman = None
        if self.filter == "kf":
            self.kalman = ConstantVelocityKalman(float(spec.noise_std_m), float(spec.dt_s), self.accel_std)

    def act(self, obs, info) -> float:
        x = self.spec.position_of(obs)
        if self.kalman is not None:
            x = self.kalman.reset(x) if self.previous is None else self.kalman.update(x)
        e = (self.target_m - x) / 1e-3
        de = 0.0 if self.previous is None else e - self.previous
        self.previous = e
        return self.kp * e + self.kd * de


class HeuristicPolicy(Policy):
    """The paper's heuristic: raise the voltage by a fixed step (0.5 V) every iteration,
    whatever the observation."""

    name = "heur"

    def __init__(self, step_V: float = 0.5):
        self.step_V = float(step_V)

    def act(self, obs, info) -> float:
        return self.step_V


# --- SAC ----------------------------------------------------------------------------------

SAC_FILE, SAC_META = "sac.zip", "sac.json"
#: the paper's SAC: actor and critics with two hidden layers of 256, soft-update τ = 0.005
SAC_HIDDEN = (256, 256)
SAC_TAU = 0.005
#: the env constants a SAC policy was trained under; it is refused on an env with others
ENV_KEYS = ("target_m", "dv_max_V", "v_max_V", "dt_s", "observation")


@dataclass(frozen=True)
class SACBudget:
    """What a SAC training cost, saved beside the weights.

    Attributes
    ----------
    timesteps : int
        Environment steps (= gradient steps: one per env step after ``learning_starts``).
    episodes : int
        Training episodes completed (ended at success or truncated).
    wall_time_s : float
    seed : int
    learning_starts : int
        Random-action steps before the first update.
    start_voltage_V : list of float
        Range of the episodes' start voltage in training (reached by a ramp from 0 V, so
        that exploration starts on the way to the target and sees the sliding stage).
    """

    timesteps: int
    episodes: int
    wall_time_s: float
    seed: int
    learning_starts: int
    start_voltage_V: list


class SACPolicy(Policy):
    """A trained stable-baselines3 SAC actor, deterministic (the mean action).

    Parameters
    ----------
    model : stable_baselines3.SAC
    meta : dict
        What :func:`train_sac` saved: the env constants it was trained under and its budget.
    """

    name = "sac"

    def __init__(self, model, meta: dict):
        self.model, self.meta = model, meta
        self.dv_max_V = float(meta["env"]["dv_max_V"])

    @property
    def training_steps(self) -> int:
        """The env steps it was trained for (its budget)."""
        return int(self.meta["budget"]["timesteps"])

    @classmethod
    def load(cls, folder: str | Path) -> "SACPolicy":
        """A policy saved by :func:`train_sac` (``sac.zip`` + ``sac.json``)."""
        from stable_baselines3 import SAC  # lazy: stable-baselines3 (~1 s) loads only for SAC
        folder = Path(folder)
        for name in (SAC_FILE, SAC_META):
            if not (folder / name).is_file():
                raise InputError(f"{folder / name}: missing; is {folder} a folder written by the SAC training?")
        meta = json.loads((folder / SAC_META).read_text())
        return cls(SAC.load(folder / SAC_FILE, device="cpu"), meta)

    def reset(self, spec) -> None:
        trained, here = self.meta["env"], env_constants(spec)
        differ = [k for k in ENV_KEYS if trained[k] != here[k]]
        if differ:
            raise InputError(f"the SAC policy was trained with {', '.join(f'{k}={trained[k]!r}' for k in differ)}; "
                             f"this env has {', '.join(f'{k}={here[k]!r}' for k in differ)}")

    def act(self, obs, info) -> float:
        action, _ = self.model.predict(np.asarray(obs, dtype=np.float32), deterministic=True)
        return float(np.clip(action[0], -1.0, 1.0)) * self.dv_max_V


def env_constants(spec) -> dict:
    """The task constants a trained policy depends on (:data:`ENV_KEYS`), from a
    :class:`~deapull.control.env.TaskSpec` (or an env: its ``task_spec()``)."""
    spec = spec.task_spec() if hasattr(spec, "task_spec") else spec
    return {"target_m": spec.target_m, "dv_max_V": spec.dv_max_V, "v_max_V": spec.v_max_V, "dt_s": spec.dt_s,
            "observation": list(spec.observation)}


def train_sac(env, out_dir: str | Path, timesteps: int, seed: int = 0, learning_starts: int = 1000,
              progress: bool = False) -> SACPolicy:
    """Train SAC on ``env`` for ``timesteps`` env steps and save it to ``out_dir``.

    The paper's settings: actor and critics 2 × 256 (ReLU), τ = 0.005, Adam, MSE critic
    loss; the rest are stable-baselines3's defaults (learning rate 3e-4, batch 256, γ = 0.99,
    one gradient step per env step, automatic entropy tuning). ``env`` should randomise its
    start voltage (:class:`~deapull.control.env.CoinPushEnv`'s ``start_voltage_V``) so that
    random exploration reaches the sliding stage; its budget is saved in ``sac.json``.

    Returns
    -------
    SACPolicy
        The trained policy (also saved: ``sac.zip``, ``sac.json``).
    """
    import torch  # lazy: the PD and the heuristic need neither torch nor stable-baselines3
    from stable_baselines3 import SAC
    from stable_baselines3.common.monitor import Monitor
    if timesteps < 1:
        raise InputError(f"SAC training timesteps {timesteps} must be at least 1")
    torch.manual_seed(seed)
    monitored = Monitor(env)
    model = SAC("MlpPolicy", monitored, tau=SAC_TAU, learning_starts=min(learning_starts, timesteps), seed=seed,
                policy_kwargs={"net_arch": list(SAC_HIDDEN)}, device="cpu", verbose=0)
    start = time.perf_counter()
    model.learn(total_timesteps=int(timesteps), progress_bar=progress)
    budget = SACBudget(timesteps=int(timesteps), episodes=len(monitored.get_episode_rewards()),
                       wall_time_s=time.perf_counter() - start, seed=seed,
                       learning_starts=min(learning_starts, timesteps), start_voltage_V=list(env.start_voltage_V))
    meta = {"env": env_constants(env), "plant": env.plant.name, "noise_std_m": env.noise_std_m,
            "episode_steps": env.max_steps, "terminate_on_success": env.terminate_on_success,
            "success_bonus": env.success_bonus,
            "hidden": list(SAC_HIDDEN), "tau": SAC_TAU, "budget": asdict(budget)}
    out = Path(out_dir)
    atomic_write(out / SAC_FILE, lambda p: model.save(p), suffix=".zip")
    write_json(out / SAC_META, meta, indent=2)
    return SACPolicy(model, meta)
