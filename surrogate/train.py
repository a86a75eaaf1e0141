"""Training (paper Algorithm 1): fit a model to the FEM's transitions, early-stopped on a
validation setup, and keep the best of several seeds on that setup.

Adam (learning rate 1e-3) on mini-batches of the training setups' transitions, up to
``epochs`` passes; after each pass the loss on the validation setup decides early stopping
(no improvement, minimum change 0, for ``patience`` passes) and the best weights are kept.
φ of each row (:class:`~deapull.surrogate.phi.Phi`, what the kind needs: m_c, μ_b and μ_t or
V^T) is the true value of its setup and stays fixed (Algorithm 1).

Restarts (model selection): with ``restarts`` = N the whole run is repeated for the seeds
``seed``, ``seed + 1``, ..., ``seed + N - 1`` and the model kept is the one whose recursive
rollout of the validation setup(s) has the lowest x error in % of travel (the quantity the
experiments report, measured on the validation setup only; ties, e.g. every rollout
diverged, go to the lower validation loss, then to the earlier seed). Every restart's
scores are recorded (:attr:`TrainResult.restarts`). The test setup is never seen.
Seeded: the same seed, restarts, data and device give the same weights on CPU, and the kept
model is bit-identical to a single run (``restarts=1``) with the chosen seed.
"""
from __future__ import annotations

import copy
import logging
import math
import time
import warnings
from dataclasses import asdict, dataclass, field

import numpy as np
import torch
from tqdm import tqdm

from deapull.errors import InputError
from deapull.surrogate.data import SetupData, transitions
from deapull.surrogate.models import KINDS, InputRange, Normalisation, Surrogate, build
from deapull.surrogate.phi import Phi

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TrainConfig:
    """Hyper-parameters of one training run.

    Attributes
    ----------
    kind : str
        ``f`` (paper's law), ``f-coulomb``, ``nn`` or ``lstm``.
    epochs : int
        Upper bound on passes over the training data (paper: 1000).
    lr : float
        Adam learning rate (paper: 1e-3).
    batch_size : int
        Transitions per Adam step.
    patience : int
        Passes without a lower validation loss before stopping.
    seed : int
        Seeds the weights and the shuffling.
    device : str
        ``cpu`` or ``cuda``.
    hidden, layers : int
        Width and depth of the MLPs (m and the NN baseline; paper: 128, 3); ``hidden`` is
        also the LSTM's state size.
    window : int
        LSTM history length (paper: 8).
    range_tolerance : float
        Relative margin of the training input range before a warning.
    restarts : int
        Seeds trained (``seed`` .. ``seed + restarts - 1``); the one with the lowest
        validation rollout x error is kept (1: a single run, no selection).
    """

    kind: str
    epochs: int = 1000
    lr: float = 1e-3
    batch_size: int = 256
    patience: int = 100
    seed: int = 0
    device: str = "cpu"
    hidden: int = 128
    layers: int = 3
    window: int = 8
    range_tolerance: float = 0.05
    restarts: int = 1

    def __post_init__(self):
        if isinstance(self.restarts, bool) or not isinstance(self.restarts, int) or self.restarts < 1:
            raise InputError(f"--restarts {self.restarts!r}: must be a whole number of at least 1 (how many seeds "
                             f"to train from --seed {self.seed}; the one whose rollout of the validation setup has "
                             f"the lowest x error is kept)")
        if self.kind not in KINDS:
            raise InputError(f"--model {self.kind!r} is not a model; choose one of {', '.join(KINDS)}")
        for name in ("epochs", "batch_size", "patience", "hidden", "layers", "window"):
            if getattr(self, name) < 1:
                raise InputError(f"{name} = {getattr(self, name)} must be at least 1")
        if not self.lr > 0:
            raise InputError(f"learning rate {self.lr} must be positive")
        resolve_device(self.device)

    def model_hparams(self, train_sets: list[SetupData]) -> dict:
        """The hyper-parameters :func:`surrogate.models.build` takes for this kind (the kind
        decides: ``training_hparams``)."""
        return KINDS[self.kind].training_hparams(self, train_sets)


def resolve_device(name: str) -> torch.device:
    """``cpu`` or ``cuda`` (only when a GPU is present)."""
    if name not in ("cpu", "cuda"):
        raise InputError(f"--device {name!r}: choose cpu or cuda")
    if name == "cuda" and not torch.cuda.is_available():
        raise InputError("--device cuda was asked for, but torch sees no CUDA device")
    return torch.device(name)


@dataclass
class TrainResult:
    """A trained model and how it got there.

    Attributes
    ----------
    model : Surrogate
        The model with the weights of the best validation epoch, on the CPU.
    config : TrainConfig
    setups : dict
        Per setup used (training and validation): file, φ, V^T and role.
    history : list of dict
        Per epoch of the kept run: ``epoch``, ``train_loss``, ``val_loss``.
    best_epoch : int
    best_val_loss : float
    wall_time_s : float
        All restarts together.
    seed : int
        The seed of the kept run.
    val_x_error_pct : float
        Its validation rollout x error (% of travel, mean over the validation runs; inf when
        a rollout diverged).
    restarts : list of dict
        One per restart, in seed order: ``seed``, ``best_epoch``, ``epochs_run``,
        ``best_val_loss``, ``val_x_error_pct``, ``val_diverged``, ``wall_time_s``, ``kept``.
    members : list of Surrogate
        Every restart's model, in seed order (the ensemble of :mod:`surrogate.ensemble`).
    val_sets : list of SetupData
        The validation runs (the ensemble's band is calibrated on them).
    phis : dict
        The φ each training and validation run was trained with, by run name.
    """

    model: Surrogate
    config: TrainConfig
    setups: dict
    history: list = field(default_factory=list)
    best_epoch: int = 0
    best_val_loss: float = math.inf
    wall_time_s: float = 0.0
    seed: int = 0
    val_x_error_pct: float = math.nan
    restarts: list = field(default_factory=list)
    members: list = field(default_factory=list)
    val_sets: list = field(default_factory=list)
    phis: dict = field(default_factory=dict)

    def summary(self) -> dict:
        return {"config": asdict(self.config), "setups": self.setups, "best_epoch": self.best_epoch,
                "best_val_loss": self.best_val_loss, "epochs_run": len(self.history),
                "wall_time_s": self.wall_time_s, "selected_seed": self.seed,
                "val_x_error_pct": self.val_x_error_pct, "selection": SELECTION, "restarts": self.restarts}


#: how :func:`train` picks among restarts (recorded with every model)
SELECTION = ("lowest validation rollout x error (% of travel, mean over the validation runs), "
             "then lowest validation loss, then earliest seed")


def setup_record(data: SetupData, role: str, phi: Phi) -> dict:
    """A setup's identity and the φ it was trained with, as saved with a model (V^T: None
    where the kind does not use it)."""
    vt = phi.value("v_threshold_V")
    return {"role": role, "file": str(data.path), "sha256": data.sha256, "fidelity": data.fidelity,
            "fidelity_id": data.fidelity_id, "steps": data.n_steps, "coin_mass_kg": data.mass_kg,
            "mu_b": data.mu_b, "mu_t": data.mu_t, "gravity_m_s2": data.gravity_m_s2, "travel_m": data.travel_m,
            "v_min_V": float(data.V.min()), "v_max_V": float(data.V.max()),
            "v_falls": bool(np.any(np.diff(data.V) < 0)), "v_threshold_V": vt if math.isfinite(vt) else None}


def train(config: TrainConfig, train_sets: list[SetupData], val_set: SetupData | list[SetupData],
          phis: dict[str, Phi] | None = None) -> TrainResult:
    """Train a model on ``train_sets``, early-stopped on ``val_set`` (Algorithm 1), once per
    restart (``config.restarts`` seeds from ``config.seed``), and keep the restart whose
    rollout of ``val_set`` has the lowest x error (:data:`SELECTION`).

    Parameters
    ----------
    config : TrainConfig
    train_sets : list of SetupData
        Runs whose transitions fit the weights (names unique: a setup, or ``<setup>_<protocol>``).
    val_set : SetupData or list of SetupData
        Run(s) whose loss (over all their transitions) decides early stopping and whose
        rollouts choose among the restarts.
    phis : dict, optional
        φ per run name, for runs whose coin the kind cannot read off the run itself (the
        paper's V^T of a release run, which never moves toward −x: the coin's ramp run gives
        it); default ``kind.phi_of(run)``.

    Returns
    -------
    TrainResult
        The kept restart, with every restart's scores in ``restarts``.
    """
    start = time.perf_counter()
    device = resolve_device(config.device)
    kind = KINDS[config.kind]
    val_sets = list(val_set) if isinstance(val_set, (list, tuple)) else [val_set]
    given = dict(phis or {})
    phis = {d.name: given[d.name] if d.name in given else kind.phi_of(d) for d in [*train_sets, *val_sets]}
    setups = {d.name: setup_record(d, "train", phis[d.name]) for d in train_sets}
    for v in val_sets:
        if v.name in setups:
            setups[v.name]["role"] = "train+val"
        else:
            setups[v.name] = setup_record(v, "val", phis[v.name])
    hparams = config.model_hparams(train_sets)
    window = hparams.get("window", 1)
    train_tr = transitions(train_sets, window, phis)
    val_tr = transitions(val_sets, window, phis).to(device)
    norm = Normalisation.from_transitions(train_tr)
    input_range = InputRange.from_transitions(train_tr, config.range_tolerance)
    train_tr = train_tr.to(device)
    log.info("training %s on %s (%d transitions), validating on %s, up to %d epochs on %s, %d restart(s)",
             config.kind, ",".join(d.name for d in train_sets), len(train_tr), ",".join(v.name for v in val_sets),
             config.epochs, device, config.restarts)
    seeds = range(config.seed, config.seed + config.restarts)
    best, records, members = None, [], []
    for seed in tqdm(seeds, desc=f"restarts {config.kind}", unit="seed", leave=False,
                     disable=None if config.restarts > 1 else True):
        run = _fit(config, seed, (norm, input_range, hparams), train_tr, val_tr, device)
        run.val_x_error_pct, diverged = validation_rollout_error(run.model, val_sets, phis)
        record = {"seed": seed, "best_epoch": run.best_epoch, "epochs_run": len(run.history),
                  "best_val_loss": run.best_val_loss, "val_x_error_pct": run.val_x_error_pct,
                  "val_diverged": diverged, "wall_time_s": run.wall_time_s, "kept": False}
        records.append(record)
        members.append(run.model)
        log.info("%s seed %d: val loss %.4g (epoch %d of %d), validation rollout x error %.4g %% of travel%s",
                 config.kind, seed, run.best_val_loss, run.best_epoch, len(run.history), run.val_x_error_pct,
                 " (diverged)" if diverged else "")
        if best is None or _rank(run) < _rank(best):
            best = run
    for record in records:
        record["kept"] = record["seed"] == best.seed
    result = TrainResult(model=best.model, config=config, setups=setups, history=best.history,
                         best_epoch=best.best_epoch, best_val_loss=best.best_val_loss,
                         wall_time_s=time.perf_counter() - start, seed=best.seed,
                         val_x_error_pct=best.val_x_error_pct, restarts=records, members=members,
                         val_sets=val_sets, phis=phis)
    log.info("%s: kept seed %d of %d restart(s): validation rollout x error %.4g %% of travel, val loss %.4g "
             "at epoch %d of %d, %.1f s in all", config.kind, result.seed, config.restarts, result.val_x_error_pct,
             result.best_val_loss, result.best_epoch, len(result.history), result.wall_time_s)
    return result


def _rank(run: TrainResult) -> tuple:
    """Sort key of a restart: validation rollout error (non-finite last), validation loss, seed."""
    err = run.val_x_error_pct if math.isfinite(run.val_x_error_pct) else math.inf
    loss = run.best_val_loss if math.isfinite(run.best_val_loss) else math.inf
    return (err, loss, run.seed)


def validation_rollout_error(model: Surrogate, val_sets: list[SetupData], phis: dict[str, Phi]) -> tuple[float, bool]:
    """The model's 1 s recursive rollout x error on the validation run(s), in % of travel.

    Each run is rolled out from its first state under its own voltages, with the φ it was
    validated with (the validation coin). Returns the mean over the runs (inf when any
    rollout diverged or gave a non-finite error) and whether one diverged.
    """
    from deapull.surrogate.evaluate import evaluate  # lazy: evaluate imports the rollout engines
    from deapull.surrogate.rollout import OutOfRangeWarning
    errors, diverged = [], False
    for v in val_sets:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", OutOfRangeWarning)
            metrics = evaluate(model, v, phi=phis[v.name]).metrics
        diverged |= metrics["diverged"]
        errors.append(metrics["x_error_pct_travel"])
    if diverged or not all(math.isfinite(e) for e in errors):
        return math.inf, diverged
    return float(sum(errors) / len(errors)), diverged


def _fit(config: TrainConfig, seed: int, parts: tuple, train_tr, val_tr, device) -> TrainResult:
    """One training run (Algorithm 1) from the weights and shuffling of ``seed``; ``parts``:
    the normalisation, input range and hyper-parameters the model is built with."""
    start = time.perf_counter()
    norm, input_range, hparams = parts
    torch.manual_seed(seed)
    shuffle = torch.Generator().manual_seed(seed)
    model = build(config.kind, norm, input_range, hparams)
    model.check_phi(train_tr.phi)
    model.check_phi(val_tr.phi)
    model.to(device)
    optimiser = torch.optim.Adam([p for p in model.parameters() if p.requires_grad], lr=config.lr)
    result = TrainResult(model=model, config=config, setups={}, seed=seed)
    best_state, waited = copy.deepcopy(model.state_dict()), 0
    bar = tqdm(range(1, config.epochs + 1), desc=f"train {config.kind} seed {seed}", unit="epoch", leave=False,
               disable=None)
    for epoch in bar:
        train_loss = _epoch(model, optimiser, train_tr, config.batch_size, shuffle)
        with torch.no_grad():
            val_loss = float(model.training_loss(val_tr))
        result.history.append({"epoch": epoch, "train_loss": train_loss, "val_loss": val_loss})
        bar.set_postfix(train=f"{train_loss:.3g}", val=f"{val_loss:.3g}")
        if not math.isfinite(train_loss):
            raise RuntimeError(f"training {config.kind} (seed {seed}) diverged at epoch {epoch} (loss {train_loss})")
        if val_loss < result.best_val_loss:
            result.best_epoch, result.best_val_loss, waited = epoch, val_loss, 0
            best_state = copy.deepcopy(model.state_dict())
        else:
            waited += 1
            if waited >= config.patience:
                log.info("seed %d: early stop at epoch %d (best %d, val loss %.4g)", seed, epoch, result.best_epoch,
                         result.best_val_loss)
                break
    model.load_state_dict(best_state)
    result.model = model.cpu()
    result.wall_time_s = time.perf_counter() - start
    return result


def _epoch(model: Surrogate, optimiser: torch.optim.Optimizer, data, batch_size: int,
           generator: torch.Generator) -> float:
    """One pass of Adam steps over shuffled mini-batches; the mean training loss."""
    model.train()
    order = torch.randperm(len(data), generator=generator).to(data.s.device)
    total = 0.0
    for start in range(0, len(data), batch_size):
        batch = data.subset(order[start:start + batch_size])
        loss = model.training_loss(batch)
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
        total += loss.item() * len(batch)
    model.eval()
    return total / len(data)
