"""Kind ``f``: the paper's f(s, a; θ, φ) = d(m(s, a; θ), s, a; φ) (eqs. 1–2).

A material network m (eq. 7: MLP 4 → 3×128 ReLU → 2) estimates the DEA's forces
z = (Fx, Fy), and the paper's law d (eqs. 4–6: threshold voltage V^T, contact loss,
frictional decay, motion only along the pull) moves the coin; φ = (m_c, μ_b, V^T).
"""
from __future__ import annotations

import math

import numpy as np
import torch

from deapull.surrogate.data import Transitions
from deapull.surrogate.models.base import (InputRange, NativeKernel, Normalisation, Surrogate, mlp, mlp_params,
                                           state_loss)
from deapull.surrogate.models.registry import register
from deapull.surrogate.phi import Phi


def paper_dynamics(z, s, a, mass_kg, mu_b, gravity, v_threshold, v_contact_loss: float) -> torch.Tensor:
    """d, the paper's law (eqs. 4–6): m_c A = Fx - F_μ along the pull (-x), with a
    voltage-ramped friction.

    The paper writes eq. 5 in magnitudes along the pulling direction: the DEA pulls with
    max(-Fx, 0) and friction F_μ = μ_b (Fy + m_c g) for V ≥ V^T, μ_b (V/V^T)(Fy + m_c g)
    below (eq. 6). For V ≥ ``v_contact_loss`` the DEA has lost the coin (Fx = Fy = 0); at
    V = 0 the DEA is off (no pull) and a moving coin decays under kinetic friction.
    Friction can stop the coin but never drive it, so the coin moves only toward -x:
    u' = -max(-u + Δt (pull - F_μ)/m_c, 0) and x' = x + Δt u'.
    """
    x, u, V, dt = s[..., 0], s[..., 1], a[..., 0], a[..., 1]
    fx, fy = z[..., 0], z[..., 1]
    contact = V < v_contact_loss
    pull = torch.where(contact & (V > 0), torch.relu(-fx), torch.zeros_like(fx))
    fy = torch.where(contact, fy, torch.zeros_like(fy))
    ramp = torch.where(V > 0, torch.clamp(V / v_threshold, max=1.0), torch.ones_like(V))
    friction = mu_b * ramp * torch.clamp(fy + mass_kg * gravity, min=0.0)
    u_next = -torch.relu(-u + dt * (pull - friction) / mass_kg)
    return torch.stack([x + dt * u_next, u_next], dim=-1)


@register
class PhysicsModel(Surrogate):
    """The paper's f = d∘m: material network m (θ) and the paper's law d (φ = (m_c, μ_b, V^T)).

    Parameters
    ----------
    norm, input_range
        See :class:`~deapull.surrogate.models.base.Surrogate`.
    hidden, layers : int
        Material network width and depth (paper: 128, 3).
    gravity_m_s2 : float
    v_contact_loss_V : float
        Voltage from which the DEA has lost the coin (inf: never).
    law : {"paper"}
        Accepted for model folders saved when this class also named the law.
    """

    kind = "f"
    label = "f (paper law)"
    physics = True
    phi_fields = ("mass_kg", "mu_b", "v_threshold_V")

    def __init__(self, norm: Normalisation, input_range: InputRange, hidden: int = 128, layers: int = 3,
                 gravity_m_s2: float = 9.8, v_contact_loss_V: float = math.inf, law: str = "paper"):
        if law != "paper":
            raise ValueError(f"law must be 'paper', not {law!r} (the Coulomb variant is kind f-coulomb)")
        hparams = {"hidden": hidden, "layers": layers, "gravity_m_s2": gravity_m_s2,
                   "v_contact_loss_V": v_contact_loss_V}
        super().__init__(norm, input_range, hparams)
        self.material = mlp(4, hidden, layers, 2)
        self.gravity_m_s2, self.v_contact_loss_V = gravity_m_s2, v_contact_loss_V

    @classmethod
    def phi_of(cls, data) -> Phi:
        """m_c, μ_b and V^T of ``data``'s own run (the paper takes a test setup's V^T from the test run)."""
        return Phi.of(data, v_threshold_V=data.threshold_voltage())

    @classmethod
    def training_hparams(cls, config, train_sets: list) -> dict:
        return {"hidden": config.hidden, "layers": config.layers, "gravity_m_s2": train_sets[0].gravity_m_s2,
                "v_contact_loss_V": min(d.contact_loss_voltage() for d in train_sets)}

    def forces(self, s: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        """m: the DEA's force on the coin z = (Fx, Fy) in N."""
        return self.z_mean + self.z_std * self.material(self.normalised_inputs(s, a))

    def dynamics(self, z, s, a, phi: Phi) -> torch.Tensor:
        """d: the next state from forces, state, action and φ (broadcast against the batch)."""
        return paper_dynamics(z, s, a, phi.mass_kg, phi.mu_b, self.gravity_m_s2, phi.v_threshold_V,
                              self.v_contact_loss_V)

    def forward(self, s: torch.Tensor, a: torch.Tensor, phi: Phi):
        """f(s, a; θ, φ) → (s', z); ``phi`` is one coin or one per row."""
        z = self.forces(s, a)
        return self.dynamics(z, s, a, self._phi(phi, s, s.dtype)), z

    def step(self, s, a, memory=None, phi: Phi | None = None):
        s_next, z = self(s, a, phi)
        return s_next, z, None

    def training_loss(self, batch: Transitions) -> torch.Tensor:
        s_next, z = self(batch.s, batch.a, batch.phi)
        return state_loss(self, s_next, z, batch)

    def native_kernel(self, phi: Phi) -> NativeKernel:
        """``deapull_rollout_physics``: norm = in_mean, in_std, z_mean, z_std;
        phys = m_c, μ_b, g, V^T, contact-loss voltage."""
        n_layers, sizes, params = mlp_params(self.material)
        norm = self.buffer_values("in_mean", "in_std", "z_mean", "z_std")
        phys = np.array([phi.value("mass_kg"), phi.value("mu_b"), self.gravity_m_s2, phi.value("v_threshold_V"),
                         self.v_contact_loss_V])
        return NativeKernel("deapull_rollout_physics", (n_layers, sizes, params, norm, phys), forces=True)
