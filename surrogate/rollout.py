"""Recursive rollouts: s_{t+1} = f(s_t, a_t), fed with the model's own states.

Two engines run the same arithmetic:

* ``torch`` — any batch, any device, differentiable (outside ``torch.no_grad``);
* ``native`` — batch 1 on the CPU, compiled C (:mod:`surrogate.native`), ~10× faster.

``engine="auto"`` takes the native one for a single rollout when gradients are off and the
kernels are available. Inputs outside the model's training range warn
(:class:`OutOfRangeWarning`), or raise :class:`OutOfRangeError` with ``strict=True``;
actions are checked before the rollout, the states it produced after it.
"""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import torch

from deapull.errors import InputError
from deapull.surrogate import native
from deapull.surrogate.models import INPUT_UNITS, INPUTS, Surrogate
from deapull.surrogate.phi import Phi

ENGINES = ("auto", "torch", "native")


class OutOfRangeWarning(UserWarning):
    """A rollout input left the range the model was trained on."""


class OutOfRangeError(InputError):
    """A rollout input left the training range and ``strict=True`` was asked for."""


@dataclass
class Rollout:
    """A rollout's result.

    Attributes
    ----------
    states : torch.Tensor
        (B, T + 1, 2): x (m) and u (m/s), starting with s0.
    forces : torch.Tensor or None
        (B, T, 2): Fx and Fy (N) that m estimated for each transition (f = d∘m only).
    engine : str
        ``torch`` or ``native``.
    wall_time_s : float
    """

    states: torch.Tensor
    forces: torch.Tensor | None
    engine: str
    wall_time_s: float


def rollout(model: Surrogate, phi: Phi | None, s0, actions, engine: str = "auto", strict: bool = False,
            label: str = "rollout") -> Rollout:
    """Simulate ``model`` recursively from ``s0`` under the action sequence ``actions``.

    Parameters
    ----------
    model : Surrogate
    phi : Phi or None
        The coin the physics models simulate (e.g. ``model.phi_of(data)``): one coin, or
        fields of shape (B,) for one per rollout; tensors that require gradients get them
        (torch engine). The black boxes take None.
    s0 : array-like
        (2,) or (B, 2) initial state (x, u).
    actions : array-like
        (T, 2) or (B, T, 2) actions (V, Δt).
    engine : {"auto", "torch", "native"}
    strict : bool
        Raise instead of warning when an input leaves the training range.
    label : str
        Names the rollout in warnings and errors.

    Returns
    -------
    Rollout
    """
    if engine not in ENGINES:
        raise InputError(f"engine {engine!r}: choose one of {', '.join(ENGINES)}")
    param = next(model.parameters())
    s0 = torch.as_tensor(s0, dtype=param.dtype, device=param.device)
    actions = torch.as_tensor(actions, dtype=param.dtype, device=param.device)
    if s0.dim() == 1:
        s0, actions = s0.unsqueeze(0), actions.unsqueeze(0)
    if s0.shape[-1] != 2 or actions.dim() != 3 or actions.shape[-1] != 2 or actions.shape[0] != s0.shape[0]:
        raise InputError(f"{label}: s0 {tuple(s0.shape)} and actions {tuple(actions.shape)} do not match "
                         "(expected (B, 2) and (B, T, 2))")
    phi = model.check_phi(phi)
    if phi is not None:
        phi = phi.to(device=param.device, dtype=param.dtype)
        if len(phi) not in (1, s0.shape[0]):
            raise InputError(f"{label}: φ holds {len(phi)} coins for {s0.shape[0]} rollouts")
    check_range(model, None, actions, strict, label)
    if engine == "auto":
        engine = "native" if (s0.shape[0] == 1 and param.device.type == "cpu" and not torch.is_grad_enabled()
                              and native.supports(model)) else "torch"
    start = time.perf_counter()
    if engine == "native":
        if s0.shape[0] != 1:
            raise InputError(f"{label}: the native engine rolls out one run at a time, got {s0.shape[0]}")
        states, forces = native.rollout(model, phi, s0[0].cpu().numpy(), actions[0].cpu().numpy())
        states = torch.from_numpy(states).unsqueeze(0)
        forces = None if forces is None else torch.from_numpy(forces).unsqueeze(0)
    else:
        states, forces = _torch_rollout(model, phi, s0, actions)
    wall = time.perf_counter() - start
    check_range(model, states, None, strict, label)
    return Rollout(states=states, forces=forces, engine=engine, wall_time_s=wall)


def _torch_rollout(model: Surrogate, phi: Phi | None, s0: torch.Tensor, actions: torch.Tensor):
    s, memory = s0, model.init_memory(s0, actions[:, 0])
    states, forces = [s0], []
    for a in actions.unbind(1):
        s, z, memory = model.step(s, a, memory, phi)
        states.append(s)
        forces.append(z)
    return torch.stack(states, 1), (torch.stack(forces, 1) if forces and forces[0] is not None else None)


def check_range(model: Surrogate, states, actions, strict: bool, label: str) -> list[str]:
    """Messages for inputs outside the training range; warn, or raise when ``strict``.

    ``states`` (B, T, 2) are checked as (x, u), ``actions`` (B, T, 2) as (V, Δt); either
    may be None. Only the first offending step of each input is reported.
    """
    low, high = model.input_range.bounds()
    messages = []
    for values, columns in ((states, (0, 1)), (actions, (2, 3))):
        if values is None:
            continue
        flat = values.detach().reshape(-1, values.shape[-1])
        for j, col in enumerate(columns):
            v = flat[:, j]
            bad = torch.nonzero((v < low[col]) | (v > high[col])).flatten()
            if bad.numel():
                i = int(bad[0])
                messages.append(f"{label}: {INPUTS[col]} = {float(v[i]):.4g} {INPUT_UNITS[col]} at step "
                                f"{i % values.shape[-2]} is outside the training range "
                                f"[{model.input_range.low[col]:.4g}, {model.input_range.high[col]:.4g}] "
                                f"{INPUT_UNITS[col]} ({bad.numel()} values outside)")
    if messages and strict:
        raise OutOfRangeError("; ".join(messages))
    for msg in messages:
        warnings.warn(msg, OutOfRangeWarning, stacklevel=3)
    return messages
