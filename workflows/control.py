"""The closed-loop experiment of ``deapull control``: policies × plants × noise levels, N
episodes each, on the coin-push env (paper §VI-B, Fig. 6).

Every argument is checked by :func:`check` before any model is loaded or any step taken
(bad input raises :class:`~deapull.errors.InputError`); :func:`resolve` then turns the
configuration, once, into what the plants and policies are built from (each model folder
loaded once: :class:`deapull.control.harness.Bench`), and the harness runs the episodes.
Each episode starts from the coin at rest at 0 V with seed ``seed + i`` (the same seeds for
every policy), runs until the true |x − x^T| first drops below the tolerance (*iterations to
target*) or the step limit, and then ``hold`` more steps: *settled* means the coin stayed
inside the window for all of them (the CSV also gives the fraction of those steps inside and
the largest error). The policy's time per iteration is the wall time of its ``act``.

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
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from deapull import provenance
from deapull import scene as scenes
from deapull.control.harness import PHI_FIELDS, Bench, Episode, Task, run_episode
from deapull.control.inference import COIN_PRIOR, PRIOR_NAMES, named_prior
from deapull.control.mpc_policy import MPC_INFERENCE, MPCConfig
from deapull.control.policies import SAC_FILE
from deapull.surrogate import store
from deapull.surrogate.data import load_setup
from deapull.surrogate.phi import Phi
from deapull.errors import InputError
from deapull.io import atomic_write, write_csv, write_json, write_text
from deapull.workflows import control_outputs
from deapull.workflows.control_outputs import summary_table  # the CLI prints it (control.summary_table)

log = logging.getLogger(__name__)

POLICIES = ("mpc", "sac", "pd", "heur", "mpc+kf", "pd+kf")
PLANT_KINDS = ("surrogate", "fem")
#: the choices of `--phi-prior`: maximum likelihood (the paper), control.inference.COIN_PRIOR (a factor 2
#: around the family) or family_prior() (the design's coins at ±1 std)
PHI_PRIORS = PRIOR_NAMES
#: where the MPC's φ comes from (:attr:`ControlConfig.mpc_phi`)
MPC_PHI = ("infer", "prior", "oracle")
COLUMNS = ("policy", "plant", "setup", "episode", "seed", "noise_std_m", "dv_max_V", "step_limit", "hold_steps",
           "setpoints_mm", "setpoints_reached", "setpoints_settled", "iterations_per_setpoint",
           "iterations_to_target", "reached", "settled", "overshoot_m", "hold_inside_fraction",
           "hold_max_abs_error_m",
           "final_abs_error_m", "final_x_m", "final_V_V", "steps_run",
           "ms_per_iteration", "solve_ms_per_iteration", "inference_ms_per_iteration", "plant_ms_per_step",
           "episode_wall_s", "fem_run",
           "training_steps", "status")
#: what ``--unreachable`` may say (ControlConfig.unreachable)
UNREACHABLE = ("refuse", "report")
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
    #: where the MPC's φ comes from: "infer" (online, :attr:`MPCConfig.inference`), "prior" (the
    #: prior's median, inferring nothing) or "oracle" (the plant's true coin)
    mpc_phi: str = "infer"
    #: the inference's prior by name (:data:`~deapull.control.inference.PRIOR_NAMES`)
    phi_prior: str = "none"
    #: the MPC's settings (a preset's [mpc] table, --set mpc.KEY=VALUE)
    mpc: MPCConfig = field(default_factory=MPCConfig)
    plant_phi: dict | None = None
    sac_dir: str = "out/models/sac{n}"
    sac_steps: int = 30000
    scene: str = "coin_pull"
    overrides: list = field(default_factory=list)
    progress: bool = True
    save_fem_runs: Path | None = None
    run_tag: str = ""
    #: a plant that cannot reach the task: "refuse" the run (exit 2) or "report" it as an
    #: unreachable row and run the other plants
    unreachable: str = "refuse"
    #: FEM plants: the target is this fraction of each plant's ramp travel (its dataset's), in
    #: place of ``target_m``; other plants keep ``target_m`` (:func:`plant_targets`)
    reach_fraction: float | None = None

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


def check(config: ControlConfig) -> dict:
    """Refuse bad settings, naming the argument, before any model is loaded. Returns the FEM
    plants that cannot reach the task, by name, with why (only with ``unreachable="report"``;
    "refuse" raises instead)."""
    if config.unreachable not in UNREACHABLE:
        raise InputError(f"--unreachable {config.unreachable!r}: choose one of {', '.join(UNREACHABLE)}")
    for name, value, low in (("--episodes", config.episodes, 1), ("--max-steps", config.max_steps, 1),
                             ("--hold", config.hold_steps, 0), ("--seed", config.seed, 0),
                             ("--sac-steps", config.sac_steps, 1)):
        if int(value) != value or value < low:
            raise InputError(f"{name} {value!r}: must be an integer >= {low}")
    if not (math.isfinite(config.dv_max_V) and config.dv_max_V > 0):
        raise InputError(f"--dv-max {config.dv_max_V!r}: must be a finite number > 0 (V per step)")
    if config.reach_fraction is not None:
        if not (math.isfinite(config.reach_fraction) and 0 < config.reach_fraction <= 1):
            raise InputError(f"--reach-fraction {config.reach_fraction!r}: must be a number in (0, 1] (a share of "
                             "each FEM plant's ramp travel)")
        missing = [str(config.data / f"{p.setup}.nc") for p in config.plants
                   if p.kind == "fem" and not (config.data / f"{p.setup}.nc").is_file()]
        if missing:
            raise InputError(f"--reach-fraction {config.reach_fraction!r} reads each plant's ramp travel from its "
                             f"dataset: missing {', '.join(missing)} (make sweep)")
    if not (math.isfinite(config.target_m) and config.target_m < 0):
        raise InputError(f"--target-mm {1e3 * config.target_m!r}: must be a finite number < 0 (the coin moves "
                         "toward -x)")
    for t in config.setpoints_m or ():
        if not (math.isfinite(t) and t < 0):
            raise InputError(f"--setpoints-mm {1e3 * t!r}: every setpoint must be a finite number < 0 (mm; the "
                             "coin moves toward -x)")
    check_plant_phi(config)
    check_inference(config)
    unreachable = check_fem(config) if any(p.kind == "fem" for p in config.plants) else {}
    for spec in config.plants:
        if _needs_surrogate(config, spec):
            _require_model(config.folder(config.plant_model, spec.setup), "--plant-model")
            if not (config.data / f"{spec.setup}.nc").is_file():
                raise InputError(f"--data {str(config.data)!r}: {spec.setup}.nc not found (the plant's coin φ "
                                 f"is read from it)")
    if any(p.startswith("mpc") for p in config.policies):
        if config.mpc_phi not in MPC_PHI:
            raise InputError(f"control.mpc_phi = {config.mpc_phi!r}: choose one of {', '.join(MPC_PHI)}")
        if config.mpc_phi == "prior" and config.phi_prior != "coins":
            raise InputError("control.mpc_phi = 'prior' plans with the prior's median: it needs --phi-prior coins")
        if config.phi_prior not in PHI_PRIORS:
            raise InputError(f"--phi-prior {config.phi_prior!r}: choose one of {', '.join(PHI_PRIORS)}")
        _require_model(Path(config.mpc_model), "--mpc-model")
        if config.mpc_phi == "infer":
            _require_inference(Path(config.mpc_model), config.mpc.inference.engine)
    return unreachable


def _require_inference(folder: Path, engine: str = "auto") -> None:
    """The MPC infers φ online with its own f_a: refuse a kind that cannot before any
    model is loaded, naming the options that plan with a given φ instead; with
    ``mpc.inference.engine = "native"``, refuse a kind without a compiled inference (or no C compiler)."""
    from deapull.control import adapters, native
    from deapull.surrogate import store
    from deapull.surrogate.models import registry
    kind = store.kind_of(folder)
    cls = registry.KINDS.get(kind)
    if cls is not None and "infer" not in adapters.capabilities(cls):
        raise InputError(f"--mpc-model {str(folder)!r}: its kind {kind!r} cannot infer φ online (capability "
                         f"'infer'); plan with a given φ: --set control.mpc_phi=prior --phi-prior coins (the "
                         f"prior's median) or --set control.mpc_phi=oracle (the plant's true φ)")
    if engine == "native" and cls is not None and native.predictor(adapters.capabilities(cls)) is None:
        raise InputError(f"mpc.inference.engine = 'native': the kind {kind!r} of --mpc-model {str(folder)!r} has no compiled "
                         f"inference here (f-coulomb and f-memory have one where a C compiler is at hand and "
                         f"DEAPULL_NATIVE is not 0); use engine auto or torch")


def check_fem(config: ControlConfig) -> dict:
    """The FEM plants' part of :func:`check`: dolfinx is installed, the scene (with ``--set``) is
    valid, and the task lies within each FEM plant's reach.

    An FEM plant's reach is its own dataset's (``--data``/<setup>.nc, the FEM of the same scene
    under the 0–400 V ramp): a target beyond the coin's travel there is refused. Without the
    dataset, or with a ``--set`` of the coin (the dataset is then another coin's run), the reach
    is not checked (one FEM ramp would cost a whole solve), and the log says so. Returns the
    plants beyond reach with the refusal's message (``unreachable="report"``; else it raises)."""
    if importlib.util.find_spec("dolfinx") is None:
        raise InputError("--plant fem:...: the FEM plant needs dolfinx (FEniCSx), which is not installed")
    task = task_of(config)
    own_targets = config.reach_fraction is not None and not config.setpoints_m   # each within its travel
    other_coin = any(o.split("=")[0].strip().startswith("coin.") for o in config.overrides)
    scenes.load(config.scene, setup=config.plants[0].setup, overrides=config.overrides)
    unreachable = {}
    for spec in config.plants:
        if spec.kind != "fem" or own_targets:
            continue
        path = config.data / f"{spec.setup}.nc"
        if other_coin:
            log.warning("%s: the target's reach is not checked: --set changes the coin, so %s is another coin's "
                        "run", spec.name, path)
        elif not path.is_file():
            log.info("%s: the target's reach is not checked (no %s to read it from)", spec.name, path)
        else:
            reach = float(np.min(load_setup(path).x))
            _judge_reach(config, spec, unreachable, task.refuse_beyond, spec.name, reach,
                         f"its FEM dataset {path} takes the coin to {1e3 * reach:.4f} mm at most (0 to 400 V)")
    if unreachable and len(unreachable) == len(config.plants):
        raise InputError("no plant can reach the task: " + "; ".join(unreachable.values()))
    return unreachable


def _require_model(folder: Path, option: str) -> None:
    if not (folder / "model.json").is_file():
        raise InputError(f"{option} {str(folder)!r}: no trained model there (model.json missing; "
                         "make one with `deapull train`)")


def _needs_surrogate(config: ControlConfig, spec: PlantSpec) -> bool:
    """Whether a run steps the surrogate of ``spec``'s setup: as the plant, or as the env that a
    SAC policy not yet in ``--sac-dir`` trains on."""
    sac_saved = (config.folder(config.sac_dir, spec.setup) / SAC_FILE).is_file()
    return spec.kind == "surrogate" or ("sac" in config.policies and not sac_saved)


# --- the configuration, resolved once ------------------------------------------------------

#: the coin fields ``--plant-phi`` may set on surrogate plants (SI units)
PLANT_PHI_FIELDS = ("mass_kg", "mu_b", "mu_t")


def parse_plant_phi(text: str | None) -> dict | None:
    """``mass_kg=2.07e-3,mu_b=0.25`` → {field: value}; checked by :func:`check_plant_phi`."""
    if not text:
        return None
    out = {}
    for item in text.split(","):
        name, sep, value = item.partition("=")
        try:
            out[name.strip()] = float(value) if sep else math.nan
        except ValueError:
            out[name.strip()] = math.nan
    return out


def check_plant_phi(config: ControlConfig) -> None:
    """``--plant-phi``: known fields, finite positive values, and surrogate plants only."""
    if not config.plant_phi:
        return
    for name, value in config.plant_phi.items():
        if name not in PLANT_PHI_FIELDS:
            raise InputError(f"--plant-phi {name!r}: unknown field; choose from {', '.join(PLANT_PHI_FIELDS)} "
                             f"(SI units, e.g. mass_kg=2.07e-3,mu_b=0.25)")
        if not (math.isfinite(value) and value > 0):
            raise InputError(f"--plant-phi {name}={value!r}: must be a finite number > 0")
    fem = [p.name for p in config.plants if p.kind == "fem"]
    if fem:
        raise InputError(f"--plant-phi sets the coin of surrogate plants only, not {', '.join(fem)} (an FEM "
                         f"plant's coin: --set coin.density_kg_m3=..., coin.mu_b=..., coin.mu_t=...)")


def check_inference(config: ControlConfig) -> None:
    """``mpc.inference.fields`` (cheap: before any folder is looked at; the rest is checked where
    :class:`~deapull.control.inference.InferenceConfig` is made)."""
    inference = config.mpc.inference
    chosen = None if inference is None else inference.fields
    unknown = [f for f in chosen or () if f not in PLANT_PHI_FIELDS]
    if unknown or (chosen is not None and not chosen):
        raise InputError(f"mpc.inference.fields = {list(chosen or ())!r}: choose one or more of "
                         f"{', '.join(PLANT_PHI_FIELDS)} (the rest stay at the prior's median)")


def plant_targets(config: ControlConfig) -> dict:
    """``reach_fraction``: each FEM plant's target, that share of its dataset's ramp travel (m), by
    setup; the other plants take ``target_m`` ({} without it, or with ``setpoints_m``, which win)."""
    if config.reach_fraction is None or config.setpoints_m:
        return {}
    return {p.setup: config.reach_fraction * float(np.min(load_setup(config.data / f"{p.setup}.nc").x))
            for p in config.plants if p.kind == "fem"}


def task_of(config: ControlConfig) -> Task:
    """What every episode of ``config`` asks: its setpoints, tolerance, |ΔV| limit and steps."""
    return Task(config.target_m, config.task, config.tolerance_m, config.dv_max_V, config.max_steps,
                config.hold_steps, option="--setpoints-mm" if config.setpoints_m else "--target-mm")


def resolve(config: ControlConfig) -> Bench:
    """A checked config (:func:`check`) as what its plants and policies are built from. Every
    folder and setting is named first; then each model folder is loaded once, however many
    plants and policies use it, and each setup's coin and scene are read once."""
    task = task_of(config)
    surrogate_dirs = {spec.setup: config.folder(config.plant_model, spec.setup)
                      for spec in config.plants if _needs_surrogate(config, spec)}
    sac_dirs = {spec.setup: config.folder(config.sac_dir, spec.setup) for spec in config.plants}
    mpc = {name: mpc_settings(config, name)
           for name in config.policies if name.startswith("mpc")}
    mpc_dir = Path(config.mpc_model)
    folders = [*surrogate_dirs.values(), *([mpc_dir] if mpc else [])]
    models = {folder: store.load(folder)[0] for folder in dict.fromkeys(folders)}
    surrogates = {setup: (models[folder], models[folder].phi_of(load_setup(config.data / f"{setup}.nc")))
                  for setup, folder in surrogate_dirs.items()}
    if config.plant_phi:                    # a coin of the user's (--plant-phi), on every surrogate plant
        surrogates = {setup: (model, replace(phi, **config.plant_phi)) for setup, (model, phi) in surrogates.items()}
    fem_scenes = {spec.setup: scenes.load(config.scene, setup=spec.setup, overrides=config.overrides)
                  for spec in config.plants if spec.kind == "fem"}
    mpc_model = models[mpc_dir] if mpc else None
    fixed_phi = None
    if mpc and config.mpc_phi == "prior":   # the fixed prior: what inference is measured against
        fixed_phi = Phi(**{f: COIN_PRIOR[f][0] for f in mpc_model.phi_fields if f in COIN_PRIOR})
    return Bench(task, surrogates, fem_scenes, config.out / "fem", sac_dirs, config.sac_steps, seed=config.seed,
                 progress=config.progress, mpc_model=mpc_model, mpc_settings=mpc, mpc_phi=fixed_phi,
                 mpc_oracle=config.mpc_phi == "oracle")


def mpc_settings(config: ControlConfig, name: str = "mpc") -> MPCConfig:
    """The settings of the MPC policy ``name`` (:mod:`deapull.control.mpc_policy`): ``config.mpc``,
    its inference on with the named prior where φ is inferred (``mpc_phi = "infer"``) and off
    otherwise; ``mpc+kf``: the plain MPC on a position-only Kalman estimate, kept to measure what
    the offset-free estimator and the terminal policy add."""
    mpc = config.mpc
    if name == "mpc+kf":
        mpc = replace(mpc, estimator=replace(mpc.estimator, kind="kf"))
    inference = None
    if config.mpc_phi == "infer":
        inference = replace(mpc.inference or MPC_INFERENCE, prior=named_prior(config.phi_prior))
    return replace(mpc, inference=inference)


# --- the experiment ------------------------------------------------------------------------

def run(config: ControlConfig) -> list[Episode]:
    """Every policy × plant × noise for ``episodes`` episodes; writes the outputs."""
    unreachable = check(config)
    bench = resolve(config)
    task = bench.task
    unreachable.update(surrogates_beyond_reach(config, bench))
    if len(unreachable) == len(config.plants):
        raise InputError("no plant can reach the task: " + "; ".join(unreachable.values()))
    config.out.mkdir(parents=True, exist_ok=True)
    packages = VERSIONED + (("dolfinx", "petsc4py") if any(p.kind == "fem" for p in config.plants) else ())
    settings = {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(config).items()}
    commit = provenance.git_commit()
    inputs = inputs_of(config)
    write_json(config.out / "run.json", {"config": settings, "git_commit": commit, "inputs": inputs,
                                         **provenance.package_versions(packages)}, indent=2)
    targets = plant_targets(config)
    total = len(config.plants) * len(config.policies) * len(config.noises) * config.episodes
    episodes: list[Episode] = []
    left_out = [unreachable_row(config, spec, name, noise, unreachable[spec.name]) for spec in config.plants
                if spec.name in unreachable for name in config.policies for noise in config.noises]
    with tqdm(total=total, desc="control episodes", unit="episode", disable=not config.progress) as bar:
        bar.update(len(left_out) * config.episodes)
        for spec in (s for s in config.plants if s.name not in unreachable):
            plant = bench.plant(spec)
            plant_task = task
            if spec.setup in targets:
                plant_task = replace(task, target_m=targets[spec.setup], setpoints_m=(targets[spec.setup],))
            for name in config.policies:
                policy = bench.policy(name, spec.setup, plant)
                for noise in config.noises:
                    env = plant_task.env(plant, noise)
                    for i in range(config.episodes):
                        bar.set_description(f"{name} on {spec.name}, noise {noise:g} m")
                        ep = run_episode(env, policy, config.seed + i, task.step_limit, task.hold_steps, bar,
                                         setpoints_m=plant_task.setpoints_m)
                        ep.row.update(setup=spec.setup, episode=i)
                        if config.save_fem_runs is not None and spec.kind == "fem" and len(plant.records) > 1:
                            stem = fem_run_name(spec.setup, config.run_tag, name, noise, i)
                            ep.row["fem_run"] = str(plant.save(Path(config.save_fem_runs) / f"{stem}.nc", stem))
                        episodes.append(ep)
                        bar.update(1)
                        if len(episodes) < total:       # so far, so that a long FEM run that stops keeps it
                            write_outputs(config.out, episodes, task, left_out, figures=False, commit=commit,
                                              inputs=inputs)
    write_outputs(config.out, episodes, task, left_out, commit=commit, inputs=inputs)
    return episodes


def surrogates_beyond_reach(config: ControlConfig, bench) -> dict:
    """The surrogate plants that cannot reach the task under the fastest push (one ramp rollout
    each, before any episode), by name, with why: ``unreachable="report"`` leaves them out as
    rows; "refuse" raises on the first (an FEM plant's reach is checked by :func:`check_fem`)."""
    unreachable = {}
    for spec in config.plants:
        if spec.kind == "surrogate":
            _judge_reach(config, spec, unreachable, bench.task.check_reach, spec.name, bench.plant(spec))
    return unreachable


def _judge_reach(config: ControlConfig, spec, unreachable: dict, refuse, *args) -> None:
    """Call the task's reach check ``refuse(*args)``; beyond reach, raise ("refuse") or note
    ``spec`` in ``unreachable`` with the message ("report")."""
    try:
        refuse(*args)
    except InputError as err:
        if config.unreachable != "report":
            raise
        log.warning("%s is left out, reported as unreachable: %s", spec.name, err)
        unreachable[spec.name] = str(err)


def unreachable_row(config: ControlConfig, spec, policy: str, noise: float, why: str) -> dict:
    """The CSV row of a plant left out because it cannot reach the task: nothing reached or
    settled, and ``status`` says why (no episode ran)."""
    return {"policy": policy, "plant": spec.name, "setup": spec.setup, "episode": 0, "seed": config.seed,
            "noise_std_m": noise, "setpoints_mm": ";".join(f"{1e3 * t:g}" for t in config.task),
            "reached": False, "settled": False, "iterations_to_target": math.nan, "overshoot_m": None,
            "final_abs_error_m": math.nan, "ms_per_iteration": math.nan, "training_steps": None, "steps_run": 0,
            "status": f"unreachable: {why}"}


def fem_run_name(setup: str, tag: str, policy: str, noise: float, episode: int) -> str:
    """File stem of a saved FEM episode (``--save-fem-runs``): setup, tag, policy, noise, episode,
    e.g. ``C3_r1_mpc_n0.0001_e0`` (a run name the surrogate's training accepts)."""
    tag = f"_{tag}" if tag else ""
    return f"{setup}{tag}_{re.sub(r'[^A-Za-z0-9]', '-', policy)}_n{noise:g}_e{episode}"


def inputs_of(config: ControlConfig) -> dict:
    """The SHA-256 of what a run reads: each model file (plants and f_a) and each plant's dataset."""
    folders = [config.folder(config.plant_model, s.setup) for s in config.plants if _needs_surrogate(config, s)]
    if any(name.startswith("mpc") for name in config.policies):
        folders.append(Path(config.mpc_model))
    data = {s.setup: config.data / f"{s.setup}.nc" for s in config.plants}
    return {"models": {str(f): provenance.file_sha256(Path(f) / store.STATE) for f in dict.fromkeys(folders)},
            "datasets": {k: provenance.file_sha256(p) for k, p in data.items() if p.is_file()}}


def write_outputs(out: Path, episodes: list[Episode], task: Task, left_out: list[dict] = (),
                  figures: bool = True, commit: str = "unknown", inputs: dict | None = None) -> None:
    """The CSV, table, traces and (``figures``) figures of the episodes; ``left_out``: rows of the
    plants that could not reach the task (in the CSV and the table, no traces); ``commit``: the git
    commit that ran them, and ``inputs`` (:func:`inputs_of`), in ``summary.json``. Written after every episode without the figures, each
    file whole (temp file, then rename)."""
    rows = [e.row for e in episodes] + list(left_out)
    columns = list(COLUMNS) + [f"{w}_{f}" for w in ("true", "inferred", "crlb") for f in PHI_FIELDS]
    write_csv(out / "control.csv", rows, columns)
    write_text(out / "table.md", summary_table(rows, task.tolerance_m) + "\n")
    write_json(out / "summary.json", {"schema": 2, "git_commit": commit, "inputs": inputs or {},
                                      "tolerance_m": task.tolerance_m,
                                      "target_m": task.target_m,
                                      "groups": control_outputs.summary_counts(rows),
                                      "table": control_outputs.summary_record(rows, task.tolerance_m)}, indent=2)
    traces = {}
    for k, e in enumerate(episodes):
        key = f"{e.row['policy']}|{e.row['plant']}|{e.row['noise_std_m']:g}|{e.row['episode']}"
        traces[f"{key}|x_m"], traces[f"{key}|V_V"] = e.x_m, e.V_V
        for f, v in e.inferred.items():
            traces[f"{key}|inferred_{f}"] = v
    atomic_write(out / "traces.npz", lambda p: np.savez_compressed(p, **traces), suffix=".npz")
    if figures:
        control_outputs.plot_all(out, episodes, task.target_m, task.tolerance_m)
