"""Training (paper Algorithm 1): fit a model to the FEM's transitions, early-stopped on a
validation setup.

Adam (learning rate 1e-3) on mini-batches of the training setups' transitions, up to
``epochs`` passes; after each pass the loss on the validation setup decides early stopping
(no improvement, minimum change 0, for ``patience`` passes) and the best weights are kept.
φ of each row (:class:`~deapull.surrogate.phi.Phi`, what the kind needs: m_c, μ_b and μ_t or
V^T) is the true value of its setup and stays fixed (Algorithm 1).
Seeded: the same seed, data and device give the same weights on CPU.
"""
from __future__ import annotations

import copy
import logging
import math
import time
from dataclasses import asdict, dataclass, field

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

    def __post_init__(self):
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
        Per epoch: ``epoch``, ``train_loss``, ``val_loss``.
    best_epoch : int
    best_val_loss : float
    wall_time_s : float
    """

    model: Surrogate
    config: TrainConfig
    setups: dict
    history: list = field(default_factory=list)
    best_epoch: int = 0
    best_val_loss: float = math.inf
    wall_time_s: float = 0.0

    def summary(self) -> dict:
        return {"config": asdict(self.config), "setups": self.setups, "best_epoch": self.best_epoch,
                "best_val_loss": self.best_val_loss, "epochs_run": len(self.history),
                "wall_time_s": self.wall_time_s}


def setup_record(data: SetupData, role: str, phi: Phi) -> dict:
    """A setup's identity and the φ it was trained with, as saved with a model (V^T: None
    where the kind does not use it)."""
    vt = phi.value("v_threshold_V")
    return {"role": role, "file": str(data.path), "steps": data.n_steps, "coin_mass_kg": data.mass_kg,
            "mu_b": data.mu_b, "mu_t": data.mu_t, "gravity_m_s2": data.gravity_m_s2, "travel_m": data.travel_m,
            "v_threshold_V": vt if math.isfinite(vt) else None}


def train(config: TrainConfig, train_sets: list[SetupData], val_set: SetupData | list[SetupData],
          phis: dict[str, Phi] | None = None) -> TrainResult:
    """Train one model on ``train_sets``, early-stopped on ``val_set`` (Algorithm 1).

    Parameters
    ----------
    config : TrainConfig
    train_sets : list of SetupData
        Runs whose transitions fit the weights (names unique: a setup, or ``<setup>_<protocol>``).
    val_set : SetupData or list of SetupData
        Run(s) whose loss (over all their transitions) decides early stopping.
    phis : dict, optional
        φ per run name, for runs whose coin the kind cannot read off the run itself (the
        paper's V^T of a release run, which never moves toward −x: the coin's ramp run gives
        it); default ``kind.phi_of(run)``.

    Returns
    -------
    TrainResult
    """
    start = time.perf_counter()
    device = resolve_device(config.device)
    torch.manual_seed(config.seed)
    shuffle = torch.Generator().manual_seed(config.seed)
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
    model = build(config.kind, Normalisation.from_transitions(train_tr),
                  InputRange.from_transitions(train_tr, config.range_tolerance), hparams)
    model.check_phi(train_tr.phi)
    model.check_phi(val_tr.phi)
    model.to(device)
    train_tr = train_tr.to(device)
    optimiser = torch.optim.Adam([p for p in model.parameters() if p.requires_grad], lr=config.lr)
    result = TrainResult(model=model, config=config, setups=setups)
    best_state, waited = copy.deepcopy(model.state_dict()), 0
    log.info("training %s on %s (%d transitions), validating on %s, up to %d epochs on %s",
             config.kind, ",".join(d.name for d in train_sets), len(train_tr), ",".join(v.name for v in val_sets),
             config.epochs, device)
    bar = tqdm(range(1, config.epochs + 1), desc=f"train {config.kind}", unit="epoch", leave=False, disable=None)
    for epoch in bar:
        train_loss = _epoch(model, optimiser, train_tr, config.batch_size, shuffle)
        with torch.no_grad():
            val_loss = float(model.training_loss(val_tr))
        result.history.append({"epoch": epoch, "train_loss": train_loss, "val_loss": val_loss})
        bar.set_postfix(train=f"{train_loss:.3g}", val=f"{val_loss:.3g}")
        if not math.isfinite(train_loss):
            raise RuntimeError(f"training {config.kind} diverged at epoch {epoch} (loss {train_loss})")
        if val_loss < result.best_val_loss:
            result.best_epoch, result.best_val_loss, waited = epoch, val_loss, 0
            best_state = copy.deepcopy(model.state_dict())
        else:
            waited += 1
            if waited >= config.patience:
                log.info("early stop at epoch %d (best %d, val loss %.4g)", epoch, result.best_epoch,
                         result.best_val_loss)
                break
    model.load_state_dict(best_state)
    result.model = model.cpu()
    result.wall_time_s = time.perf_counter() - start
    log.info("%s: best val loss %.4g at epoch %d of %d, %.1f s", config.kind, result.best_val_loss,
             result.best_epoch, len(result.history), result.wall_time_s)
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
