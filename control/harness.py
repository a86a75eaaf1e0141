"""The closed-loop bench that ``deapull control`` (:mod:`deapull.workflows.control`) runs:
the task every episode asks (:class:`Task`), the plants and policies it builds from models,
scenes and settings already resolved (:class:`Bench`), and one episode of a policy on the
coin-push env (:func:`run_episode`).

Nothing here reads a command line or a run's configuration: every model, folder and number
comes in as an argument.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from deapull.control.env import V_MAX_V, CoinPushEnv, policy_view
from deapull.control.mpc_policy import MPCPolicy
from deapull.control.plants import FEMPlant, PlantFailed, SurrogatePlant, ramp_reach_m
from deapull.control.policies import SAC_FILE, HeuristicPolicy, PDPolicy, SACPolicy, train_sac
from deapull.errors import InputError
from deapull.surrogate.phi import Phi

#: steps at V_max after the fastest ramp in the reach check (the coin coasts to rest well within)
REACH_HOLD_STEPS = 1000
#: φ fields reported (true and inferred)
PHI_FIELDS = ("mass_kg", "mu_b", "mu_t", "v_threshold_V")
#: per-iteration wall times (lists of ms) that a policy may keep: the MPC's plan and inference
TIMED = ("solve_ms", "inference_ms")
#: SAC training when no trained policy is found: episode length and start voltages (V)
SAC_EPISODE_STEPS = 500
SAC_START_VOLTAGE_V = (0.0, 350.0)
#: reward added at each training step inside the window (the env's ``success_bonus``): without it
#: the ±0.01 mm window is worth 0.01 per step against returns of order −50, and SAC stops ~20 µm
#: short (docs/control.md)
SAC_SUCCESS_BONUS = 1.0


# --- what an episode asks, what it runs ----------------------------------------------------

@dataclass(frozen=True)
class Task:
    """What every episode asks of a plant: the setpoints taken in turn within ``tolerance_m``,
    under the |ΔV| limit ``dv_max_V``, each for at most ``step_limit`` steps and then held
    ``hold_steps`` more. ``target_m`` is the env's own target (the setpoints' first replaces it
    at every reset); ``option`` is the argument that set the setpoints (a refusal names it)."""

    target_m: float
    setpoints_m: tuple
    tolerance_m: float
    dv_max_V: float
    step_limit: int
    hold_steps: int
    option: str = "--target-mm"

    def env(self, plant, noise_std_m: float, **kwargs) -> CoinPushEnv:
        """The coin-push env of ``plant`` with room for the whole task (``kwargs``: other env
        options, over these)."""
        options = dict(target_m=self.target_m, tolerance_m=self.tolerance_m, dv_max_V=self.dv_max_V,
                       max_steps=(self.step_limit + self.hold_steps) * len(self.setpoints_m),
                       noise_std_m=noise_std_m, terminate_on_success=False)
        return CoinPushEnv(plant, **{**options, **kwargs})

    def check_reach(self, plant_name: str, plant) -> None:
        """Refuse the task when ``plant`` (a surrogate: one ramp rollout is cheap) cannot reach its
        furthest setpoint under the |ΔV| limit (:func:`ramp_reach_m`); never move the setpoint."""
        steps = math.ceil(V_MAX_V / self.dv_max_V) + REACH_HOLD_STEPS
        reach = ramp_reach_m(plant, self.dv_max_V, V_MAX_V, steps)
        self.refuse_beyond(plant_name, reach, f"its coin gets to {1e3 * reach:.4f} mm at most under the fastest "
                           f"push (+{self.dv_max_V:g} V per step to {V_MAX_V:g} V, then held {REACH_HOLD_STEPS} "
                           "steps)")

    def refuse_beyond(self, plant_name: str, reach_m: float, how: str) -> None:
        """Exit 2 (InputError) when the furthest setpoint lies beyond ``reach_m``, naming the
        option, the plant and ``how`` the reach was found."""
        furthest = min(self.setpoints_m)
        if reach_m > furthest + self.tolerance_m:
            raise InputError(f"{self.option} {1e3 * furthest:g}: {plant_name} cannot reach it; {how}; choose a "
                             "target within reach")


@dataclass(frozen=True)
class Bench:
    """What the plants and policies of a run are built from, resolved before its first episode:

    * per setup, the surrogate that simulates its coin (a trained model and the coin's φ) and
      the scene of its FEM plant (meshed in ``fem_dir``/<setup>);
    * per setup, the folder of its SAC policy, and what a SAC policy not found there trains on
      (the setup's surrogate plant in the task's env, ``sac_steps`` steps from ``seed``);
    * the MPC's f_a and its settings per policy name (``mpc``, ``mpc+kf``), and the φ it plans
      with when it infers none (``mpc_phi``, e.g. a prior's median; ``mpc_oracle``: the
      plant's true φ).
    """

    task: Task
    surrogates: dict                        # setup -> (model, φ)
    scenes: dict                            # setup -> scene
    fem_dir: Path
    sac_dirs: dict                          # setup -> folder
    sac_steps: int
    seed: int = 0
    progress: bool = True
    mpc_model: object = None
    mpc_settings: dict = field(default_factory=dict)
    mpc_phi: Phi | None = None
    mpc_oracle: bool = False

    def plant(self, spec):
        """The plant of ``spec`` (``surrogate:C1``, ``fem:C1``: its ``kind``, ``setup`` and ``name``)."""
        if spec.kind == "surrogate":
            return self.surrogate(spec.setup)
        return FEMPlant(self.scenes[spec.setup], work_dir=self.fem_dir / spec.setup, name=spec.name)

    def surrogate(self, setup: str) -> SurrogatePlant:
        """f_s of ``setup``: the surrogate simulating the setup's coin."""
        model, phi = self.surrogates[setup]
        return SurrogatePlant(model, phi, name=f"surrogate:{setup}")

    def policy(self, name: str, setup: str, plant):
        """The policy ``name`` (``pd``, ``pd+kf``, ``heur``, ``sac``, ``mpc``, ``mpc+kf``) for
        ``plant`` of ``setup``."""
        if name in ("pd", "pd+kf"):
            return PDPolicy(filter="kf" if name == "pd+kf" else "none")
        if name == "heur":
            return HeuristicPolicy()
        if name == "sac":
            return self.sac(setup)
        return MPCPolicy(self.mpc_model, self.mpc_settings[name], phi=plant.truth if self.mpc_oracle else self.mpc_phi)

    def sac(self, setup: str):
        """The SAC policy of ``setup``: loaded from its folder, or trained there first on the
        surrogate env of the setup (noise 0, ``sac_steps`` steps).

        It trains on the task it is judged on: an episode goes on past the first entry into the
        window (``terminate_on_success=False``), and each step inside earns
        :data:`SAC_SUCCESS_BONUS`, so the return rewards staying there. The paper's episode ends
        at the first entry: a SAC trained so has no value for what comes after, rushes in and
        never settles (docs/control.md)."""
        folder = self.sac_dirs[setup]
        if (folder / SAC_FILE).is_file():
            policy = SACPolicy.load(folder)
            if not policy.meta.get("success_bonus"):
                print(f"note: the SAC policy in {folder} was trained without the bonus inside the window "
                      "(an older policy, or one trained by hand): it may reach and not settle; remove the folder to retrain it here")
            return policy
        env = self.task.env(self.surrogate(setup), 0.0, max_steps=SAC_EPISODE_STEPS,
                            terminate_on_success=False, start_voltage_V=SAC_START_VOLTAGE_V,
                            success_bonus=SAC_SUCCESS_BONUS)
        print(f"training SAC on {env.plant.name} for {self.sac_steps} steps -> {folder}")
        return train_sac(env, folder, self.sac_steps, seed=self.seed, progress=self.progress)


# --- one episode ---------------------------------------------------------------------------

@dataclass
class Episode:
    """One episode's row (the columns of ``deapull control``'s CSV, true and inferred φ) and its
    per-step traces (index 0: the state after reset)."""

    row: dict
    x_m: np.ndarray
    V_V: np.ndarray
    inferred: dict


def run_episode(env, policy, seed: int, step_limit: int, hold_steps: int, bar=None,
                setpoints_m: tuple | None = None) -> Episode:
    """Run ``policy`` on ``env`` (``terminate_on_success=False``, ``max_steps`` ≥
    ``(step_limit + hold_steps)`` × the number of setpoints) from ``reset(seed)``.

    ``setpoints_m`` (default: the env's target alone) are taken in turn: each runs until the
    true |x − x^T| first drops below the tolerance (*reached*; its iterations count from the
    setpoint's start) or ``step_limit`` steps pass, then ``hold_steps`` more (*settled*: inside
    for all of them); a setpoint never reached ends the episode. *Overshoot* is how far the
    coin went past a setpoint in the direction it was approached. A plant failure ends the
    episode with its message as ``status``.
    """
    setpoints = tuple(float(t) for t in (setpoints_m or (env.target_m,)))
    started = time.perf_counter()
    obs, info = env.reset(seed=seed)
    env.set_target(setpoints[0])
    info = {**info, "target_m": setpoints[0]}
    policy.reset(env.task_spec())
    xs, Vs, inferred = [info["x_m"]], [env.V], {}
    act_s = plant_s = 0.0
    status, phases = "ok", []
    try:
        for k, target in enumerate(setpoints):
            if k:
                env.set_target(target)
                info = {**info, "target_m": target}
            start_step, x_start = info["step"], info["x_m"]
            direction = 1.0 if target > x_start else -1.0
            phase = {"target_m": target, "reached": None, "inside": [], "overshoot_m": 0.0, "hold_error_m": 0.0}
            phases.append(phase)
            while True:
                start = time.perf_counter()
                dV = float(policy.act(obs, policy_view(info)))
                act_s += time.perf_counter() - start
                start = time.perf_counter()
                obs, _, _, _, info = env.step(env.action_of(dV))
                plant_s += time.perf_counter() - start
                xs.append(info["x_m"])
                Vs.append(info["V_V"])
                for key, v in policy.inferred().items():
                    inferred.setdefault(key, []).append(v)
                phase["overshoot_m"] = max(phase["overshoot_m"], direction * (info["x_m"] - target))
                if phase["reached"] is None and info["success"]:
                    phase["reached"] = info["step"] - start_step
                if phase["reached"] is not None:
                    phase["inside"].append(info["success"])
                    phase["hold_error_m"] = max(phase["hold_error_m"], abs(info["x_m"] - target))
                if bar is not None and info["step"] % 100 == 0:
                    bar.set_postfix_str(f"step {info['step']}", refresh=False)
                if phase["reached"] is None and info["step"] - start_step >= step_limit:
                    break
                if len(phase["inside"]) > hold_steps:
                    break
            if phase["reached"] is None:
                break
    except PlantFailed as err:
        status = f"plant failed: {err}"
    n = len(xs) - 1
    for phase in phases:
        phase["settled"] = phase["reached"] is not None and len(phase["inside"]) > hold_steps and all(phase["inside"])
    inside = [s for phase in phases for s in phase["inside"]]
    first, last = phases[0], phases[-1]
    estimate = {k: v[-1] for k, v in inferred.items()}
    truth = env.plant.truth.as_dict() if env.plant.truth is not None else {}
    all_reached = len(phases) == len(setpoints) and all(ph["reached"] is not None for ph in phases)
    row = {"policy": policy.name, "plant": env.plant.name, "seed": seed, "noise_std_m": env.noise_std_m,
           "dv_max_V": env.dv_max_V, "step_limit": step_limit, "hold_steps": hold_steps,
           "setpoints_mm": ";".join(f"{1e3 * t:g}" for t in setpoints),
           "setpoints_reached": sum(ph["reached"] is not None for ph in phases),
           "setpoints_settled": sum(ph["settled"] for ph in phases),
           "iterations_to_target": first["reached"], "reached": all_reached,
           "settled": all_reached and all(ph["settled"] for ph in phases),
           "iterations_per_setpoint": ";".join(str(ph["reached"]) for ph in phases),
           "hold_inside_fraction": float(np.mean(inside)) if inside else None,
           "hold_max_abs_error_m": max(ph["hold_error_m"] for ph in phases) if all_reached else None,
           "overshoot_m": max(ph["overshoot_m"] for ph in phases),
           "final_abs_error_m": abs(xs[-1] - last["target_m"]), "final_x_m": xs[-1], "final_V_V": Vs[-1],
           "steps_run": n, "ms_per_iteration": 1e3 * act_s / max(n, 1), "plant_ms_per_step": 1e3 * plant_s / max(n, 1),
           "episode_wall_s": time.perf_counter() - started,
           "status": status, "training_steps": getattr(policy, "training_steps", None), **_timings(policy),
           **{f"true_{f}": truth.get(f) for f in PHI_FIELDS},
           **{f"inferred_{f}": estimate.get(f) for f in PHI_FIELDS},
           **{f"crlb_{f}": estimate.get(f"crlb_{f}") for f in PHI_FIELDS}}
    return Episode(row, np.array(xs), np.array(Vs), {k: np.array(v) for k, v in inferred.items()})


def _timings(policy) -> dict:
    """Mean per-iteration times a policy reports itself (the MPC: plan and inference, ms)."""
    return {f"{k}_per_iteration": float(np.mean(getattr(policy, k))) if getattr(policy, k, None) else None
            for k in TIMED}
