"""The closed-loop experiment of ``deapull control``: policies × plants × noise levels, N
episodes each, on the coin-push env (paper §VI-B, Fig. 6).

Every argument is checked by :func:`check` before any model is loaded or any step taken
(bad input raises :class:`~deapull.errors.InputError`). Each episode starts from the coin
at rest at 0 V with seed ``seed + i`` (the same seeds for every policy), runs until the
true |x − x^T| first drops below the tolerance (*iterations to target*) or the step limit,
and then ``hold`` more steps: *settled* means the coin stayed inside the window for all of
them (the CSV also gives the fraction of those steps inside and the largest error). The
policy's time per iteration is the wall time of its ``act``.

Outputs in ``--out`` (every file written atomically):

* ``control.csv`` — one row per episode (:data:`COLUMNS`, plus the true φ, the inferred φ and
  its Cramér–Rao bounds);
* ``table.md`` — per policy, plant, noise and task: reached/settled counts, iterations to
  target, final error, overshoot and time per iteration, beside the paper's numbers
  (``deapull.paper.CONTROL``; :mod:`deapull.workflows.control_outputs`);
* ``position_<plant>_noise<σ>.png`` — the paper's Fig. 6: mean coin position per policy
  with its 25–75 % band over the episodes; ``voltage_<plant>_noise<σ>.png`` — V(t);
  ``inferred_<plant>_noise<σ>.png`` — inferred φ per iteration beside the true value, and each
  inferred field's Cramér–Rao bound on its relative error (``crlb_*``; policies that infer);
* ``traces.npz`` — every episode's x, V (and inferred φ) per step; ``run.json`` — the
  configuration, versions and commit.
"""
from __future__ import annotations

import importlib.util
import logging
import math
import re
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from deapull import provenance
from deapull import scene as scenes
from deapull.control.dynamics import COSTS
from deapull.control.env import CoinPushEnv, V_MAX_V, policy_view
from deapull.control.inference import COIN_PRIOR, InferenceConfig
from deapull.control.mpc_policy import MPCConfig, MPCPolicy
from deapull.control.plants import FEMPlant, PlantFailed, SurrogatePlant, ramp_reach_m
from deapull.control.policies import HeuristicPolicy, PDPolicy, SACPolicy, SAC_FILE, train_sac
from deapull.surrogate import store
from deapull.surrogate.data import load_setup
from deapull.surrogate.phi import Phi
from deapull.errors import InputError
from deapull.io import atomic_write, write_csv, write_json, write_text
from deapull.workflows import control_outputs
from deapull.workflows.control_outputs import summary_table  # the CLI prints it (control.summary_table)

log = logging.getLogger(__name__)
#: steps at V_max after the fastest ramp in the reach check (the coin coasts to rest well within)
REACH_HOLD_STEPS = 1000

POLICIES = ("mpc", "sac", "pd", "heur", "mpc+kf", "pd+kf")
PLANT_KINDS = ("surrogate", "fem")
#: the choices of `--phi-prior`: maximum likelihood (the paper) or control.inference.COIN_PRIOR
PHI_PRIORS = ("none", "coins")
#: φ fields reported (true and inferred)
PHI_FIELDS = ("mass_kg", "mu_b", "mu_t", "v_threshold_V")
COLUMNS = ("policy", "plant", "setup", "episode", "seed", "noise_std_m", "dv_max_V", "step_limit", "hold_steps",
           "setpoints_mm", "setpoints_reached", "setpoints_settled", "iterations_per_setpoint",
           "iterations_to_target", "reached", "settled", "overshoot_m", "hold_inside_fraction",
           "hold_max_abs_error_m",
           "final_abs_error_m", "final_x_m", "final_V_V", "steps_run",
           "ms_per_iteration", "solve_ms_per_iteration", "inference_ms_per_iteration", "plant_ms_per_step",
           "episode_wall_s", "fem_run",
           "training_steps", "status")
#: per-iteration wall times (lists of ms) that a policy may keep: the MPC's plan and inference
TIMED = ("solve_ms", "inference_ms")
#: SAC training when no trained policy is found: episode length and start voltages (V)
SAC_EPISODE_STEPS = 500
SAC_START_VOLTAGE_V = (0.0, 350.0)
#: packages whose versions run.json records (+ dolfinx, petsc4py with an FEM plant)
VERSIONED = ("numpy", "torch", "gymnasium", "stable_baselines3")


@dataclass(frozen=True)
class PlantSpec:
    """``surrogate:C1`` or ``fem:C1``."""

    kind: str
    setup: str

    @property
    def name(self) -> str:
        return f"{self.kind}:{self.setup}"


@dataclass
class ControlConfig:
    """Everything ``deapull control`` runs (see ``deapull control --help`` for each).

    ``plant_model`` and ``sac_dir`` are patterns: ``{setup}`` becomes the setup (C1) and
    ``{n}`` its number (1).
    """

    policies: list
    plants: list
    noises: list
    out: Path
    episodes: int = 10
    seed: int = 0
    dv_max_V: float = 5.0
    max_steps: int = 4000
    hold_steps: int = 100
    target_m: float = -1e-3
    setpoints_m: list | None = None
    tolerance_m: float = 1e-5
    data: Path = Path("data")
    plant_model: str = "out/models/fs{n}"
    mpc_model: str = "out/models/fa"
    mpc_cost: str = "scaled"
    mpc_oracle: bool = False
    mpc_no_infer: bool = False
    mpc_approach_m: float = 0.0
    mpc_max_rate_V: float = 0.0
    mpc_standoff: float = 0.0
    phi_prior: str = "none"
    infer_optimizer: str = "lm"
    sac_dir: str = "out/models/sac{n}"
    sac_steps: int = 30000
    scene: str = "coin_pull"
    overrides: list = field(default_factory=list)
    progress: bool = True
    save_fem_runs: Path | None = None
    run_tag: str = ""

    @property
    def task(self) -> tuple:
        """The setpoints an episode visits in turn: ``setpoints_m``, or the target alone."""
        return tuple(self.setpoints_m) if self.setpoints_m else (self.target_m,)

    def folder(self, pattern: str, setup: str) -> Path:
        return Path(pattern.format(setup=setup, n=re.sub(r"\D", "", setup)))


# --- argument checks (before any work) -----------------------------------------------------

def parse_list(text: str, what: str) -> list[str]:
    items = [s.strip() for s in str(text).split(",") if s.strip()]
    if not items:
        raise InputError(f"{what} {text!r}: empty")
    return list(dict.fromkeys(items))


def parse_policies(text: str) -> list[str]:
    out = parse_list(text, "--policy")
    for p in out:
        if p not in POLICIES:
            raise InputError(f"--policy {p!r}: unknown policy; choose from {', '.join(POLICIES)}")
    return out


def parse_plants(text: str, scene: str = "coin_pull") -> list[PlantSpec]:
    setups = scenes.setups_of(scene)
    out = []
    for item in parse_list(text, "--plant"):
        kind, _, setup = item.partition(":")
        if kind not in PLANT_KINDS or not setup:
            raise InputError(f"--plant {item!r}: expected KIND:SETUP with KIND one of {', '.join(PLANT_KINDS)} "
                             f"(e.g. surrogate:C1, fem:C1)")
        if setup not in setups:
            raise InputError(f"--plant {item!r}: unknown setup {setup!r}; scene {scene!r} has {', '.join(setups)}")
        out.append(PlantSpec(kind, setup))
    return out


def parse_noises(text: str) -> list[float]:
    out = []
    for item in parse_list(text, "--noise"):
        try:
            value = float(item)
        except ValueError:
            raise InputError(f"--noise {item!r}: not a number (std of the observation noise, m)") from None
        if not (math.isfinite(value) and value >= 0):
            raise InputError(f"--noise {item!r}: must be a finite number >= 0 (std of the observation noise, m)")
        out.append(value)
    return out


def check(config: ControlConfig, mpc_model_trained: bool = True) -> None:
    """Refuse bad settings, naming the argument, before any model is loaded.
    ``mpc_model_trained=False``: the MPC's model is made later (``deapull dagger``'s round 0),
    so its folder is not required yet."""
    for name, value, low in (("--episodes", config.episodes, 1), ("--max-steps", config.max_steps, 1),
                             ("--hold", config.hold_steps, 0), ("--seed", config.seed, 0),
                             ("--sac-steps", config.sac_steps, 1)):
        if int(value) != value or value < low:
            raise InputError(f"{name} {value!r}: must be an integer >= {low}")
    if not (math.isfinite(config.dv_max_V) and config.dv_max_V > 0):
        raise InputError(f"--dv-max {config.dv_max_V!r}: must be a finite number > 0 (V per step)")
    if not (math.isfinite(config.target_m) and config.target_m < 0):
        raise InputError(f"--target-mm {1e3 * config.target_m!r}: must be a finite number < 0 (the coin moves "
                         "toward -x)")
    for t in config.setpoints_m or ():
        if not (math.isfinite(t) and t < 0):
            raise InputError(f"--setpoints-mm {1e3 * t!r}: every setpoint must be a finite number < 0 (mm; the "
                             "coin moves toward -x)")
    if any(p.kind == "fem" for p in config.plants):
        if importlib.util.find_spec("dolfinx") is None:
            raise InputError("--plant fem:...: the FEM plant needs dolfinx (FEniCSx), which is not installed")
        scenes.load(config.scene, setup=config.plants[0].setup, overrides=config.overrides)
        for spec in config.plants:
            if spec.kind == "fem":
                fem_reach(config, spec)
    for spec in config.plants:
        needs_surrogate = spec.kind == "surrogate" or ("sac" in config.policies and not _sac_saved(config, spec))
        if needs_surrogate:
            _require_model(config.folder(config.plant_model, spec.setup), "--plant-model")
            if not (config.data / f"{spec.setup}.nc").is_file():
                raise InputError(f"--data {str(config.data)!r}: {spec.setup}.nc not found (the plant's coin φ "
                                 f"is read from it)")
    if any(p.startswith("mpc") for p in config.policies):
        if config.mpc_cost not in COSTS:
            raise InputError(f"--mpc-cost {config.mpc_cost!r}: choose one of {', '.join(COSTS)}")
        if not (math.isfinite(config.mpc_standoff) and config.mpc_standoff >= 0):
            raise InputError(f"--mpc-standoff {config.mpc_standoff!r}: must be a finite number >= 0 (stds)")
        if not (math.isfinite(config.mpc_max_rate_V) and config.mpc_max_rate_V >= 0):
            raise InputError(f"--mpc-max-rate {config.mpc_max_rate_V!r}: must be a finite number >= 0 (V per step)")
        if not (math.isfinite(config.mpc_approach_m) and config.mpc_approach_m >= 0):
            raise InputError(f"--mpc-approach-mm {1e3 * config.mpc_approach_m!r}: must be a finite number >= 0 (mm)")
        if config.mpc_no_infer and (config.phi_prior != "coins" or config.mpc_oracle):
            raise InputError("--mpc-no-infer plans with the prior's median: it needs --phi-prior coins and no "
                             "--mpc-oracle")
        if config.phi_prior not in PHI_PRIORS:
            raise InputError(f"--phi-prior {config.phi_prior!r}: choose one of {', '.join(PHI_PRIORS)}")
        if mpc_model_trained:
            _require_model(Path(config.mpc_model), "--mpc-model")


def _require_model(folder: Path, option: str) -> None:
    if not (folder / "model.json").is_file():
        raise InputError(f"{option} {str(folder)!r}: no trained model there (model.json missing; "
                         "make one with `deapull train`)")


def _sac_saved(config: ControlConfig, spec: PlantSpec) -> bool:
    return (config.folder(config.sac_dir, spec.setup) / SAC_FILE).is_file()


# --- plants and policies -------------------------------------------------------------------

def surrogate_plant(config: ControlConfig, setup: str):
    """f_s of ``setup``: the surrogate in ``--plant-model`` simulating the setup's coin."""
    model, _ = store.load(config.folder(config.plant_model, setup))
    phi = model.phi_of(load_setup(config.data / f"{setup}.nc"))
    return SurrogatePlant(model, phi, name=f"surrogate:{setup}")


def build_plant(config: ControlConfig, spec: PlantSpec):
    if spec.kind == "surrogate":
        return surrogate_plant(config, spec.setup)
    scene = scenes.load(config.scene, setup=spec.setup, overrides=config.overrides)
    return FEMPlant(scene, work_dir=config.out / "fem" / spec.setup, name=spec.name)


def make_env(config: ControlConfig, plant, noise_std_m: float, **kwargs):
    options = dict(target_m=config.target_m, tolerance_m=config.tolerance_m, dv_max_V=config.dv_max_V,
                   max_steps=(config.max_steps + config.hold_steps) * len(config.task), noise_std_m=noise_std_m,
                   terminate_on_success=False)
    return CoinPushEnv(plant, **{**options, **kwargs})


def sac_policy(config: ControlConfig, setup: str):
    """The SAC policy of ``setup``: loaded from ``--sac-dir``, or trained there first on the
    surrogate env of the setup (noise 0, ``--sac-steps`` steps)."""
    folder = config.folder(config.sac_dir, setup)
    if _sac_saved(config, PlantSpec("surrogate", setup)):
        return SACPolicy.load(folder)
    env = make_env(config, surrogate_plant(config, setup), 0.0, max_steps=SAC_EPISODE_STEPS,
                   terminate_on_success=True, start_voltage_V=SAC_START_VOLTAGE_V)
    print(f"training SAC on {env.plant.name} for {config.sac_steps} steps -> {folder}")
    return train_sac(env, folder, config.sac_steps, seed=config.seed, progress=config.progress)


def build_policy(config: ControlConfig, name: str, spec: PlantSpec, plant):
    if name in ("pd", "pd+kf"):
        return PDPolicy(filter="kf" if name == "pd+kf" else "none")
    if name == "heur":
        return HeuristicPolicy()
    if name == "sac":
        return sac_policy(config, spec.setup)
    return mpc_policy(config, plant, filter="kf" if name == "mpc+kf" else "none")


def mpc_policy(config: ControlConfig, plant, filter: str = "none"):
    """The MPC (:mod:`deapull.control.mpc_policy`) planning with f_a from ``--mpc-model``: φ inferred
    online, or the plant's true φ with ``--mpc-oracle``; ``filter="kf"``: from a Kalman
    estimate of the position (``mpc+kf``)."""
    model, _ = store.load(config.mpc_model)
    prior = {"none": None, "coins": COIN_PRIOR}[config.phi_prior]
    # mpc: offset-free (gain-error filter, hold inside the window); mpc+kf: the earlier MPC on a
    # position-only Kalman estimate, kept to measure what the offset-free parts add
    plain = filter == "kf"
    settings = MPCConfig(cost=config.mpc_cost, infer=not config.mpc_oracle, filter=filter,
                         offset_free=not plain, hold_band=0.0 if plain else MPCConfig.hold_band,
                         approach_m=0.0 if plain else config.mpc_approach_m,
                         max_rate_V=0.0 if plain else config.mpc_max_rate_V,
                         standoff_stds=0.0 if plain else config.mpc_standoff,
                         inference=InferenceConfig(optimizer=config.infer_optimizer, prior=prior))
    if config.mpc_no_infer:                 # the fixed prior: what inference is measured against
        median = Phi(**{f: COIN_PRIOR[f][0] for f in model.phi_fields if f in COIN_PRIOR})
        return MPCPolicy(model, replace(settings, infer=False), phi=median)
    return MPCPolicy(model, settings, phi=plant.truth if config.mpc_oracle else None)


# --- one episode ---------------------------------------------------------------------------

@dataclass
class Episode:
    """One episode's row (:data:`COLUMNS`, true and inferred φ) and its per-step traces
    (index 0: the state after reset)."""

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


# --- the experiment ------------------------------------------------------------------------

def run(config: ControlConfig) -> list[Episode]:
    """Every policy × plant × noise for ``episodes`` episodes; writes the outputs."""
    check(config)
    config.out.mkdir(parents=True, exist_ok=True)
    packages = VERSIONED + (("dolfinx", "petsc4py") if any(p.kind == "fem" for p in config.plants) else ())
    settings = {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(config).items()}
    write_json(config.out / "run.json", {"config": settings, "git_commit": provenance.git_commit(),
                                         **provenance.package_versions(packages)}, indent=2)
    total = len(config.plants) * len(config.policies) * len(config.noises) * config.episodes
    episodes: list[Episode] = []
    with tqdm(total=total, desc="control episodes", unit="episode", disable=not config.progress) as bar:
        for spec in config.plants:
            plant = build_plant(config, spec)
            check_reach(config, spec, plant)
            for name in config.policies:
                policy = build_policy(config, name, spec, plant)
                for noise in config.noises:
                    env = make_env(config, plant, noise)
                    for i in range(config.episodes):
                        bar.set_description(f"{name} on {spec.name}, noise {noise:g} m")
                        ep = run_episode(env, policy, config.seed + i, config.max_steps, config.hold_steps, bar,
                                         setpoints_m=config.task)
                        ep.row.update(setup=spec.setup, episode=i)
                        if config.save_fem_runs is not None and spec.kind == "fem" and len(plant.records) > 1:
                            stem = fem_run_name(config, spec, name_of=name, noise=noise, episode=i)
                            ep.row["fem_run"] = str(plant.save(Path(config.save_fem_runs) / f"{stem}.nc", stem))
                        episodes.append(ep)
                        bar.update(1)
    write_outputs(config, episodes)
    return episodes


def fem_run_name(config: ControlConfig, spec: PlantSpec, name_of: str, noise: float, episode: int) -> str:
    """File stem of a saved FEM episode (``--save-fem-runs``): setup, tag, policy, noise, episode,
    e.g. ``C3_r1_mpc_n0.0001_e0`` (a run name the surrogate's training accepts)."""
    tag = f"_{config.run_tag}" if config.run_tag else ""
    return f"{spec.setup}{tag}_{re.sub(r'[^A-Za-z0-9]', '-', name_of)}_n{noise:g}_e{episode}"


def check_reach(config: ControlConfig, spec: PlantSpec, plant) -> None:
    """Refuse a target the plant cannot reach under the |ΔV| limit (:func:`ramp_reach_m`), never
    move it. A surrogate plant is checked by one ramp rollout, an FEM plant against its own
    dataset's travel (:func:`fem_reach`)."""
    if spec.kind != "surrogate":
        return                              # checked before any work (check: fem_reach)
    steps = math.ceil(V_MAX_V / config.dv_max_V) + REACH_HOLD_STEPS
    reach = ramp_reach_m(plant, config.dv_max_V, V_MAX_V, steps)
    _refuse_beyond(config, spec, reach, f"its coin gets to {1e3 * reach:.4f} mm at most under the fastest push "
                   f"(+{config.dv_max_V:g} V per step to {V_MAX_V:g} V, then held {REACH_HOLD_STEPS} steps)")


def _refuse_beyond(config: ControlConfig, spec: PlantSpec, reach_m: float, how: str) -> None:
    """Exit 2 (InputError) when the task's furthest setpoint lies beyond ``reach_m``, naming the
    option, the plant and ``how`` the reach was found."""
    furthest = min(config.task)
    if reach_m > furthest + config.tolerance_m:
        option = "--setpoints-mm" if config.setpoints_m else "--target-mm"
        raise InputError(f"{option} {1e3 * furthest:g}: {spec.name} cannot reach it; {how}; choose a target "
                         "within reach")


def fem_reach(config: ControlConfig, spec: PlantSpec) -> None:
    """An FEM plant's reach is its own dataset's (``--data``/<setup>.nc, the FEM of the same
    scene under the 0–400 V ramp): a target beyond the coin's travel there is refused. Without
    the dataset, or with a ``--set`` of the coin (the dataset is then another coin's run), the
    reach is not checked (one FEM ramp would cost a whole solve), and the log says so."""
    path = config.data / f"{spec.setup}.nc"
    if any(o.split("=")[0].strip().startswith("coin.") for o in config.overrides):
        log.warning("%s: the target's reach is not checked: --set changes the coin, so %s is another coin's run",
                    spec.name, path)
        return
    if not path.is_file():
        log.info("%s: the target's reach is not checked (no %s to read it from)", spec.name, path)
        return
    reach = float(np.min(load_setup(path).x))
    _refuse_beyond(config, spec, reach, f"its FEM dataset {path} takes the coin to {1e3 * reach:.4f} mm at most "
                   "(0 to 400 V)")


def write_outputs(config: ControlConfig, episodes: list[Episode]) -> None:
    rows = [e.row for e in episodes]
    columns = list(COLUMNS) + [f"{w}_{f}" for w in ("true", "inferred", "crlb") for f in PHI_FIELDS]
    write_csv(config.out / "control.csv", rows, columns)
    write_text(config.out / "table.md", summary_table(rows) + "\n")
    traces = {}
    for k, e in enumerate(episodes):
        key = f"{e.row['policy']}|{e.row['plant']}|{e.row['noise_std_m']:g}|{e.row['episode']}"
        traces[f"{key}|x_m"], traces[f"{key}|V_V"] = e.x_m, e.V_V
        for f, v in e.inferred.items():
            traces[f"{key}|inferred_{f}"] = v
    atomic_write(config.out / "traces.npz", lambda p: np.savez_compressed(p, **traces), suffix=".npz")
    control_outputs.plot_all(config, episodes)
