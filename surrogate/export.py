"""A trained ``f-coulomb`` model as one TorchScript file that needs neither deapull nor Python.

:func:`export` compiles the model's 1 s rollout, s_{t+1} = f(s_t, a_t; φ), into a
:class:`TipContactRollout` module and saves it with :func:`torch.jit.save`::

    states, forces = torch.jit.load("model.ts")(s0, actions, phi)

``s0`` is (x, u) in m and m/s (shape (2,)), ``actions`` the (V, Δt) of each step (T, 2)
in V and s, ``phi`` the coin (m_c in kg, μ_b, μ_t) (3,), all float64; ``states`` is (T + 1, 2)
and ``forces`` (Fx, Fy) in N (T, 2). The compiled step is the model's own: the material
network m, copied, and the coin's step :func:`~deapull.surrogate.models.tip_contact.coin_step`,
compiled from its source; the module rounds the state to the network's float32 after each
step as the torch rollout does, so the two agree to round-off (tested within 1e-9 m). A
C++ program loads the file with ``torch::jit::load``. The file's ``extra_files`` carry the
model card (``model.json``) it was made from.
"""
from __future__ import annotations

import copy
import json
from pathlib import Path

import torch
from torch import nn

from deapull.errors import InputError
from deapull.io import atomic_write
from deapull.surrogate.models import TipContactModel
from deapull.surrogate.models.tip_contact import coin_step

#: the file name :func:`export` writes beside a model's ``model.pt``
EXPORT = "model.ts"


def supports(model) -> bool:
    """Whether ``model``'s kind has a TorchScript export (f-coulomb)."""
    return type(model) is TipContactModel


class TipContactRollout(nn.Module):
    """The recursive rollout of a :class:`~deapull.surrogate.models.TipContactModel` (kind
    ``f-coulomb``), in TorchScript's subset of Python."""

    def __init__(self, model: TipContactModel):
        super().__init__()
        if not supports(model):
            raise InputError(f"model kind {model.kind!r} has no TorchScript export; exported: f-coulomb")
        self.material = copy.deepcopy(model.material).float().eval()
        for name in ("in_mean", "in_std", "s_std", "z_mean", "z_std"):
            self.register_buffer(name, getattr(model, name).detach().clone().float())
        self.gravity = float(model.gravity_m_s2)
        self.register_buffer("eps", torch.tensor(float(model.slip_rate_reg_m_s), dtype=torch.float64))
        self.iterations = int(model.iterations)

    def material_response(self, V: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """m: the tip's stroke X(V) (m, X(0) = 0) and pressing force Fy(V) (N), float32."""
        scaled = torch.stack([V, torch.zeros_like(V)], dim=-1).unsqueeze(-1)
        out = self.material((scaled - self.in_mean[2]) / self.in_std[2])
        return self.s_std[0] * (out[..., 0, 0] - out[..., 1, 0]), self.z_mean[1] + self.z_std[1] * out[..., 0, 1]

    def forward(self, s0: torch.Tensor, actions: torch.Tensor, phi: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        mass, mu_b, mu_t = phi[0].double(), phi[1].double(), phi[2].double()
        s = s0.float().reshape(1, 2)
        stroke_prev = torch.zeros(1, dtype=torch.float32)
        states = [s]
        forces = []
        for a in actions.float().unbind(0):
            a = a.reshape(1, 2)
            stroke, fy = self.material_response(a[..., 0])
            sd, ad = s.double(), a.double()
            dt, fyd = ad[..., 1], fy.double()
            normal = torch.clamp(mass * self.gravity + fyd, min=0.0)
            w = (stroke.double() - stroke_prev.double()) / dt
            u_next, fx = coin_step(sd[..., 1], w, mu_t * torch.clamp(fyd, min=0.0), mu_b * normal, mass, dt,
                                   self.eps, self.iterations)
            s = torch.stack([sd[..., 0] + dt * u_next, u_next], dim=-1).float()
            forces.append(torch.stack([fx, fyd], dim=-1).float())
            states.append(s)
            stroke_prev = stroke
        return torch.cat(states, 0).double(), torch.cat(forces, 0).double()


def export(model: TipContactModel, path: str | Path, card: dict | None = None) -> Path:
    """Compile ``model``'s rollout with TorchScript and save it to ``path`` (atomically); the
    model card ``card`` (its ``model.json``) travels inside the file as ``model.json``."""
    scripted = torch.jit.script(TipContactRollout(model))
    extra = {"model.json": json.dumps(card or {})}
    path = Path(path)
    atomic_write(path, lambda p: torch.jit.save(scripted, str(p), _extra_files=extra))
    return path


def load(path: str | Path) -> tuple[torch.jit.ScriptModule, dict]:
    """An exported rollout and the model card it carries."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such exported model (written by `deapull export`)")
    extra = {"model.json": ""}
    module = torch.jit.load(str(path), map_location="cpu", _extra_files=extra)
    return module, json.loads(extra["model.json"] or "{}")
