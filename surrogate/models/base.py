"""What every model kind shares: the training data's normalisation and input range, the
MLP, and the :class:`Surrogate` interface.

A model kind is a :class:`Surrogate` subclass in its own module, registered under its name
(:func:`deapull.surrogate.models.register`). It declares

* ``kind`` (the name), ``label`` (for tables), ``physics`` (an f = d∘m rather than a
  black box) and ``phi_fields`` (the fields of :class:`~deapull.surrogate.phi.Phi` its
  dynamics uses; empty for the black boxes);
* ``step(s, a, memory, phi)``, ``init_memory`` and ``training_loss(batch)``;
* ``training_hparams(config, train_sets)``: its hyper-parameters for a training run;
* optionally ``phi_of(data)`` (how to get its φ from a dataset) and
  ``native_kernel(phi)`` (the C function of ``native_rollout.c`` that rolls it out, with
  its arguments), so that neither the trainer nor the rollout engines dispatch on kinds.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import nn

from deapull.errors import InputError
from deapull.surrogate.data import DatasetError, Transitions
from deapull.surrogate.phi import FIELDS, Phi

INPUTS = ("x", "u", "V", "dt")
INPUT_UNITS = ("m", "m/s", "V", "s")


@dataclass(frozen=True)
class Normalisation:
    """Means and scales of the training data (each a list of floats, SI units).

    Attributes
    ----------
    in_mean, in_std : list of float
        Of the inputs (x, u, V, Δt).
    z_mean, z_std : list of float
        Of the forces (Fx, Fy).
    s_std : list of float
        Of the states (x, u): scale of the state error in the loss (eq. 3).
    ds_std : list of float
        Of the one-step state changes (x' - x, u' - u): output scale of the black boxes.
    """

    in_mean: list
    in_std: list
    z_mean: list
    z_std: list
    s_std: list
    ds_std: list

    @classmethod
    def from_transitions(cls, tr: Transitions) -> "Normalisation":
        inputs = torch.cat([tr.s, tr.a], dim=1).double()
        z, s, ds = tr.z.double(), tr.s.double(), (tr.s_next - tr.s).double()
        return cls(in_mean=inputs.mean(0).tolist(), in_std=_scale(inputs),
                   z_mean=z.mean(0).tolist(), z_std=_scale(z), s_std=_scale(s), ds_std=_scale(ds))

    def to_dict(self) -> dict:
        return asdict(self)


def _scale(values: torch.Tensor) -> list:
    """Standard deviation per column; a constant column gets |mean| (or 1 when that is 0)."""
    std, mean = values.std(0, unbiased=False), values.mean(0).abs()
    return torch.where(std > 0, std, torch.where(mean > 0, mean, torch.ones_like(mean))).tolist()


@dataclass(frozen=True)
class InputRange:
    """The box of inputs (x, u, V, Δt) seen in training, with a relative tolerance.

    An input counts as outside when it leaves [low - tol·span, high + tol·span].
    """

    low: list
    high: list
    tolerance: float = 0.05

    @classmethod
    def from_transitions(cls, tr: Transitions, tolerance: float = 0.05) -> "InputRange":
        inputs = torch.cat([tr.s, tr.a], dim=1).double()
        return cls(low=inputs.min(0).values.tolist(), high=inputs.max(0).values.tolist(), tolerance=tolerance)

    def bounds(self) -> tuple[list, list]:
        """Lower and upper admissible value of each input."""
        span = [h - lo for lo, h in zip(self.low, self.high)]
        return ([lo - self.tolerance * w for lo, w in zip(self.low, span)],
                [h + self.tolerance * w for h, w in zip(self.high, span)])

    def to_dict(self) -> dict:
        return {"inputs": list(INPUTS), "units": list(INPUT_UNITS), **asdict(self)}


def mlp(n_in: int, hidden: int, layers: int, n_out: int) -> nn.Sequential:
    """Fully connected net: ``layers`` hidden layers of ``hidden`` ReLU units."""
    mods, width = [], n_in
    for _ in range(layers):
        mods += [nn.Linear(width, hidden), nn.ReLU()]
        width = hidden
    mods.append(nn.Linear(width, n_out))
    return nn.Sequential(*mods)


@dataclass(frozen=True)
class NativeKernel:
    """A call of one C function of ``native_rollout.c`` (see :mod:`deapull.surrogate.native`).

    The function takes ``args`` (ints, and numpy arrays of float32, float64 or C int, passed
    as pointers), then ``n_steps, s0, actions, states`` and, when ``forces``, the forces
    array; it returns 0, or -1 when it cannot allocate memory.
    """

    name: str
    args: tuple
    forces: bool


def mlp_params(net: nn.Sequential) -> tuple[int, np.ndarray, np.ndarray]:
    """An MLP as the C kernels read it: (number of layers, sizes (C int), float32 weights
    and biases layer by layer, row-major)."""
    linears = [m for m in net if isinstance(m, nn.Linear)]
    sizes = np.array([linears[0].in_features] + [m.out_features for m in linears], dtype=np.intc)
    flat = np.concatenate([t.detach().cpu().float().reshape(-1).numpy() for m in linears for t in (m.weight, m.bias)])
    return len(linears), sizes, np.ascontiguousarray(flat, dtype=np.float32)


class Surrogate(nn.Module):
    """Base class: the training data's normalisation and input range, as buffers.

    Parameters
    ----------
    norm : Normalisation
    input_range : InputRange
    hparams : dict
        Hyper-parameters that rebuild the model (saved in its JSON).
    """

    kind = ""
    label = ""
    #: an f = d∘m (forces and a coin), rather than a black box
    physics = False
    #: the fields of φ the dynamics uses (:class:`~deapull.surrogate.phi.Phi`)
    phi_fields: tuple = ()
    #: coins of different friction margins a training run needs to identify the model; a kind
    #: that needs more than one sits out the paper's sets (one training coin each)
    training_coins = 1
    window = 1
    def __init__(self, norm: Normalisation, input_range: InputRange, hparams: dict):
        super().__init__()
        self.norm, self.input_range, self.hparams = norm, input_range, dict(hparams)
        for name, values in norm.to_dict().items():
            self.register_buffer(name, torch.tensor(values, dtype=torch.float32))

    # --- φ -----------------------------------------------------------------------------

    @classmethod
    def phi_of(cls, data) -> Phi:
        """φ of ``data``'s coin (a :class:`~deapull.surrogate.data.SetupData`) for this kind.

        Raises
        ------
        DatasetError
            Naming the file and the attribute, when the dataset lacks a field this kind needs.
        """
        phi = Phi.of(data)
        cls._require_attributes(data, phi)
        return phi

    @classmethod
    def _require_attributes(cls, data, phi: Phi) -> None:
        for f in cls.phi_fields:
            attribute = FIELDS[f][2]
            if attribute is not None and not phi.value(f) >= 0:
                raise DatasetError(f"{data.path}: attribute {attribute!r} is missing: the {cls.kind} model needs "
                                   f"{FIELDS[f][1]}")

    def check_phi(self, phi: Phi | None) -> Phi | None:
        """Refuse a φ without the fields this kind needs (:attr:`phi_fields`), naming them."""
        if not self.phi_fields:
            return phi
        if not isinstance(phi, Phi):
            raise InputError(f"model kind {self.kind!r} needs φ = ({', '.join(self.phi_fields)}) as a "
                             f"deapull.surrogate.phi.Phi (e.g. model.phi_of(data)), got {type(phi).__name__}")
        return phi.require(self.phi_fields, f"model kind {self.kind!r}")

    def _phi(self, phi: Phi | None, like: torch.Tensor, dtype: torch.dtype | None = None) -> Phi:
        """``phi`` as tensors on ``like``'s device (cheap check only: see :meth:`check_phi`)."""
        if not isinstance(phi, Phi) or any(getattr(phi, f) is None for f in self.phi_fields):
            self.check_phi(phi)
        return phi.to(device=like.device, dtype=dtype)

    # --- the model ---------------------------------------------------------------------

    @classmethod
    def training_hparams(cls, config, train_sets: list) -> dict:
        """The hyper-parameters of a model trained with ``config`` (a
        :class:`~deapull.surrogate.train.TrainConfig`) on ``train_sets``."""
        return {"hidden": config.hidden, "layers": config.layers}

    def normalised_inputs(self, s: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        """(x, u, V, Δt) → zero-mean, unit-scale network inputs."""
        return (torch.cat([s, a], dim=-1) - self.in_mean) / self.in_std

    def init_memory(self, s0: torch.Tensor, a0: torch.Tensor):
        """The rollout memory before the first step (None for memoryless models)."""
        return None

    def step(self, s: torch.Tensor, a: torch.Tensor, memory=None, phi: Phi | None = None):
        """One transition: ``(s', z, memory')`` from state s (..., 2) and action a (..., 2)
        of the coin ``phi`` (one φ, or one per row)."""
        raise NotImplementedError

    def training_loss(self, batch: Transitions) -> torch.Tensor:
        """The loss minimised in training, on normalised quantities (φ of each row: ``batch.phi``)."""
        raise NotImplementedError

    native_kernel = None
    """``native_kernel(phi) -> NativeKernel``: defined by the kinds that have a C kernel."""

    def buffer_values(self, *names: str) -> np.ndarray:
        """The buffers ``names`` (normalisation), concatenated as one float64 array."""
        return np.concatenate([getattr(self, n).detach().cpu().double().numpy() for n in names])


def state_loss(model: Surrogate, s_next, z, batch: Transitions) -> torch.Tensor:
    """Eq. 3: mean squared error of z and of s', each normalised by its scale."""
    return (((z - batch.z) / model.z_std) ** 2).mean() + (((s_next - batch.s_next) / model.s_std) ** 2).mean()

