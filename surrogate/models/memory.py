"""Kind ``f-memory``: the tip-contact f with the memory the physics needs (the tip-memory model).

The tip-contact model (``f-coulomb``) moves the DEA's contact point rigidly with a stroke
X(V) of the voltage alone. The FEM's tip is compliant: the friction T it transmits to the
coin bends it back, and when the voltage turns (a triangle's peak, a release, a random
input, a controller backing off) the friction reverses, so the contact point lags X(V) by
T/k one way on loading and the other way on unloading — a hysteresis of ~2 μ_b N / k
(≈ 0.1 mm, 8 % of the travel) that no map of V can hold. The pressing force follows
the same state: on the shipped FEM, Fy = Fy₀(V) + b·Fx with b = −0.19 on loading and
unloading alike (its r.m.s. residual falls from 1.5e-3 N to 4e-5 N, C1 triangle and
ramp–hold–ramp).

So the DEA's part, m (θ), an MLP 1 → 3×128 ReLU → 4 of the voltage, gives

* the free stroke X(V) = σ_x [m₁(V) − m₁(0)] of the contact point (X(0) = 0),
* the pressing force at zero friction Fy₀(V) = μ_Fy + σ_Fy m₂(V),
* the tip's tangential compliance c(V) = 1/k = c₀ softplus(m₃(V) + 1) > 0 (c₀ = 1/200 m/N),
* the friction–pressing coupling b(V) = tanh(m₄(V)/5) ∈ (−1, 1) (near 0 at the start),

and the memory is the tip's state: the voltage, the contact point's position P and the
friction force T of the previous step. d (φ = (m_c, μ_b, μ_t)) takes one backward-Euler step
of two unknowns, the coin velocity u' and the friction T':

    T' = (X(V') − P') / c(V')                       the tip is a spring from its free stroke
    T' = μ_t Fy⁺ s/√(s² + ε_v²),  s = (P' − P)/Δt − u'  the FEM's rate-regularised tip friction
    m_c (u' − u)/Δt = T' − B,  B ∈ μ_b N Sgn(u')       the ground's exact Coulomb stick/slip
    Fy = Fy₀(V') + b(V') T',  N = max(m_c g + Fy, 0),  x' = x + Δt u',  z = (T', Fy)

Eliminating P' and u' leaves one equation g(T') = 0 whose left side increases strictly in T'
(|μ_t b| < 1, |μ_b b| < 1), so the step has one solution in the bracket
|T'| ≤ μ_t |Fy₀| / (1 − μ_t |b|); a bracketed Newton solve finds it without gradients and one
Newton correction with them gives the gradients of the exact root (implicit differentiation).
Stick and slip of both contacts and the friction reversal come out of it: when the voltage
turns, the tip first sticks to the coin while T' swings through zero (P' stays, X moves), the
coin stops, and once T' exceeds μ_b N it drags the coin back — toward the clamp in a release.
With c → 0 it is the tip-contact model again.

Training is one-step (Algorithm 1) with the memory taken from the data (teacher forcing): the
voltage and the FEM's Fx before the step, P = X(V) − c(V) Fx; the rollout carries its own.
The loss is eq. 3 on (x', u', Fx) through the step and on Fy as the relation
Fy₀(V) + b(V)·Fx at the FEM's Fx (see :meth:`TipMemoryModel.training_loss`).
A rollout starts with the DEA at rest at its first voltage with no friction (the FEM places
the DEA on the coin frictionless).
"""
from __future__ import annotations

import math

import torch

from deapull.surrogate.data import Transitions
from deapull.surrogate.models.base import InputRange, Normalisation, Surrogate
from deapull.surrogate.models.registry import register
from deapull.surrogate.models.tip_contact import TipFriction
from deapull.surrogate.phi import Phi

#: scale of the tip's tangential compliance (m/N): the shipped DEA's tip has k ≈ 210 N/m
COMPLIANCE_SCALE = 1.0 / 200.0


def _reg(s, eps):
    return s / torch.sqrt(s * s + eps * eps)


def tip_memory_step(u, P, X_next, c, fy0, b, mu_t, mu_b, mass_kg, dt, g: float, eps: float,
                    iterations: int = 60, T_start=None):
    """d of the tip-memory model: (u', T', Fy', P') of one step (see the module docstring).

    Parameters
    ----------
    u, P : torch.Tensor
        Coin velocity (m/s) and the contact point's position (m) before the step.
    X_next, c, fy0, b : torch.Tensor
        m at the step's voltage: free stroke (m), compliance (m/N), pressing force at zero
        friction (N) and the friction–pressing coupling.
    mu_t, mu_b, mass_kg : torch.Tensor or float
        φ.
    dt : torch.Tensor
        The step (s).
    g, eps : float
        Gravity (m/s²) and the friction's slip-rate regularisation ε_v (m/s).
    iterations : int
        Most bracketed Newton iterations (they stop once no row changes).
    T_start : torch.Tensor, optional
        Where the solve starts (the previous step's friction: it changes little per step);
        default 0.

    Returns
    -------
    (u_next, T, Fy, P_next)
    """
    ratio = mass_kg / dt

    def parts(T):
        fy = fy0 + b * T
        normal = torch.clamp(mass_kg * g + fy, min=0.0)
        reach = T + ratio * u
        cap = mu_b * normal
        slip = reach.abs() > cap
        sgn = torch.where(reach >= 0, torch.ones_like(reach), -torch.ones_like(reach))
        u_next = torch.where(slip, (reach - sgn * cap) / ratio, torch.zeros_like(reach))
        P_next = X_next - c * T
        s = (P_next - P) / dt - u_next
        return fy, u_next, P_next, s, slip, sgn

    def residual(T):
        fy, u_next, P_next, s, slip, sgn = parts(T)
        return T - mu_t * torch.clamp(fy, min=0.0) * _reg(s, eps)

    def slope(T):
        fy, u_next, P_next, s, slip, sgn = parts(T)
        pressing = (fy > 0).to(T.dtype)
        du = torch.where(slip, (1.0 - sgn * mu_b * b * ((mass_kg * g + fy) > 0).to(T.dtype)) / ratio,
                         torch.zeros_like(T))
        ds = -c / dt - du
        dreg = eps * eps / (s * s + eps * eps) ** 1.5
        return 1.0 - mu_t * (pressing * b * _reg(s, eps) + torch.clamp(fy, min=0.0) * dreg * ds)

    with torch.no_grad():
        bound = (mu_t * fy0.abs() / (1.0 - mu_t * b.abs())) * (1 + 1e-9) + 1e-15
        lo, hi = -bound, bound
        T = torch.zeros_like(bound) if T_start is None else torch.minimum(torch.maximum(T_start.detach(), lo), hi)
        change = hi - lo
        for _ in range(iterations):
            r = residual(T)
            lo, hi = torch.where(r < 0, T, lo), torch.where(r >= 0, T, hi)
            step = r / slope(T)
            bisect = (T - step < lo) | (T - step > hi) | (2 * step.abs() > change.abs()) | ~torch.isfinite(step)
            T, previous = torch.where(bisect, 0.5 * (lo + hi), T - step), T
            change = T - previous
            if bool(torch.all(change.abs() <= 1e-14 * (T.abs() + 1e-9))):
                break
    T = T - residual(T) / slope(T).detach()
    fy, u_next, P_next, s, slip, sgn = parts(T)
    return u_next, T, fy, P_next


def tip_memory_step_scalar(u, P, X_next, c, fy0, b, mu_t, mu_b, mass_kg, dt, g: float, eps: float,
                           iterations: int = 60, T_start: float = 0.0):
    """:func:`tip_memory_step` for one row in Python floats (no gradients): the same
    bracketed Newton solve, ~100× faster than small torch operations for a batch-1 rollout."""
    ratio = mass_kg / dt

    def parts(T):
        fy = fy0 + b * T
        normal = max(mass_kg * g + fy, 0.0)
        reach = T + ratio * u
        cap = mu_b * normal
        sgn = 1.0 if reach >= 0 else -1.0
        slip = abs(reach) > cap
        u_next = (reach - sgn * cap) / ratio if slip else 0.0
        P_next = X_next - c * T
        return fy, u_next, P_next, (P_next - P) / dt - u_next, slip, sgn

    def residual_slope(T):
        fy, u_next, P_next, s, slip, sgn = parts(T)
        root = math.sqrt(s * s + eps * eps)
        reg = s / root
        fyp = max(fy, 0.0)
        du = (1.0 - sgn * mu_b * b * (1.0 if mass_kg * g + fy > 0 else 0.0)) / ratio if slip else 0.0
        dreg = eps * eps / root ** 3
        slope = 1.0 - mu_t * ((b if fy > 0 else 0.0) * reg + fyp * dreg * (-c / dt - du))
        return T - mu_t * fyp * reg, slope

    bound = (mu_t * abs(fy0) / (1.0 - mu_t * abs(b))) * (1 + 1e-9) + 1e-15
    lo, hi = -bound, bound
    T = min(max(T_start, lo), hi)
    change = hi - lo
    for _ in range(iterations):
        r, slope = residual_slope(T)
        if r < 0:
            lo = T
        else:
            hi = T
        step = r / slope if slope != 0 else math.inf
        new = T - step
        if not (lo <= new <= hi) or 2 * abs(step) > abs(change) or not math.isfinite(step):
            new = 0.5 * (lo + hi)
        change, T = new - T, new
        if abs(change) <= 1e-14 * (abs(T) + 1e-9):
            break
    r, slope = residual_slope(T)
    T = T - r / slope
    fy, u_next, P_next, s, slip, sgn = parts(T)
    return u_next, T, fy, P_next


@register
class TipMemoryModel(TipFriction, Surrogate):
    """The tip-contact f with the tip's memory: compliance, friction reversal, Fy(V, T)
    (kind ``f-memory``; see the module docstring).

    Parameters
    ----------
    norm, input_range
        See :class:`~deapull.surrogate.models.base.Surrogate`.
    hidden, layers : int
    gravity_m_s2 : float
    slip_rate_reg_m_s : float
        ε_v of the tip–coin friction (the FEM scene's ``contact.slip_rate_regularisation_m_s``).
    iterations : int
        Most iterations of the step's root solve.
    """

    kind = "f-memory"
    label = "f (tip memory)"
    physics = True

    def __init__(self, norm: Normalisation, input_range: InputRange, hidden: int = 128, layers: int = 3,
                 gravity_m_s2: float = 9.8, slip_rate_reg_m_s: float = 1e-4, iterations: int = 60):
        self._init_tip(norm, input_range, 4, hidden, layers, gravity_m_s2, slip_rate_reg_m_s, iterations)

    def material_response(self, V: torch.Tensor):
        """m: (X(V) (m, X(0) = 0), Fy₀(V) (N), c(V) (m/N), b(V)) at the voltages ``V``."""
        scaled = torch.stack([V, torch.zeros_like(V)], dim=-1).unsqueeze(-1)
        out = self.material((scaled - self.in_mean[2]) / self.in_std[2])
        stroke = self.s_std[0] * (out[..., 0, 0] - out[..., 1, 0])
        fy0 = self.z_mean[1] + self.z_std[1] * out[..., 0, 1]
        compliance = COMPLIANCE_SCALE * torch.nn.functional.softplus(out[..., 0, 2] + 1.0)
        return stroke, fy0, compliance, torch.tanh(0.2 * out[..., 0, 3])

    def init_memory(self, s0, a0):
        """(V, P, T) before the first step: the first voltage is set by :meth:`step` on its
        first call (memory None); a given memory is used as is."""
        return None

    def rest_memory(self, V0: torch.Tensor) -> torch.Tensor:
        """Memory of the DEA at rest at ``V0`` without friction (P = X(V0), T = 0)."""
        stroke, _, _, _ = self.material_response(V0)
        return torch.stack([V0, stroke.to(V0.dtype), torch.zeros_like(V0)], dim=-1)

    def memory_from_data(self, v_prev: torch.Tensor, fx_prev: torch.Tensor) -> torch.Tensor:
        """Memory (V, P, T) before a transition from the recorded voltage and Fx there."""
        stroke, _, compliance, _ = self.material_response(v_prev)
        return torch.stack([v_prev, stroke - compliance * fx_prev, fx_prev], dim=-1)

    def dynamics(self, s, a, memory, phi: Phi):
        """d in float64: (s', z, memory')."""
        s, a, memory = s.double(), a.double(), memory.double()
        phi = self._phi(phi, s, torch.float64)
        stroke, fy0, compliance, b = (t.double() for t in self.material_response(a[..., 0].to(self.in_mean.dtype)))
        dt = a[..., 1]
        if s.shape[0] == 1 and s.dim() == 2 and not torch.is_grad_enabled() and phi.mass_kg.numel() == 1:
            out = tip_memory_step_scalar(float(s[0, 1]), float(memory[0, 1]), float(stroke[0]), float(compliance[0]),
                                         float(fy0[0]), float(b[0]), float(phi.mu_t), float(phi.mu_b),
                                         float(phi.mass_kg), float(dt[0]), self.gravity_m_s2, self.slip_rate_reg_m_s,
                                         self.iterations, float(memory[0, 2]))
            u_next, T, fy, P_next = (torch.tensor([v], dtype=torch.float64, device=s.device) for v in out)
            s_next = torch.stack([s[..., 0] + dt * u_next, u_next], dim=-1)
            return s_next, torch.stack([T, fy], dim=-1), torch.stack([a[..., 0], P_next, T], dim=-1)
        u_next, T, fy, P_next = tip_memory_step(s[..., 1], memory[..., 1], stroke, compliance, fy0, b, phi.mu_t,
                                                phi.mu_b, phi.mass_kg, dt, self.gravity_m_s2, self.slip_rate_reg_m_s,
                                                self.iterations, memory[..., 2])
        s_next = torch.stack([s[..., 0] + dt * u_next, u_next], dim=-1)
        return s_next, torch.stack([T, fy], dim=-1), torch.stack([a[..., 0], P_next, T], dim=-1)

    def forward(self, s, a, v_prev, fx_prev, phi: Phi):
        """f(s, a; θ, φ) → (s', z) from the recorded voltage and Fx before the step."""
        memory = self.memory_from_data(v_prev, fx_prev)
        s_next, z, _ = self.dynamics(s, a, memory, phi)
        return s_next.to(s.dtype), z.to(s.dtype)

    def step(self, s, a, memory=None, phi: Phi | None = None):
        if memory is None:
            # a rollout's first step starts from the DEA at rest at the first action's start:
            # the voltage before it is that of the run's first point, which the action does not
            # carry; rollouts from 0 V (every FEM run but the release) and from V_max
            # (release) both start at a[0] within the first step's change
            memory = self.rest_memory(a[..., 0])
        s_next, z, memory = self.dynamics(s, a, memory, phi)
        return s_next.to(s.dtype), z.to(s.dtype), memory.to(s.dtype)

    def training_loss(self, batch: Transitions) -> torch.Tensor:
        """Eq. 3 with the memory from the data; the pressing force is compared as the FEM's
        relation Fy = Fy₀(V) + b(V) Fx at the recorded Fx (an equation error: through the
        solve, Fy's gradient passes the stiff tip friction and training stalled in a poor
        minimum on the test sweep), the state and Fx through the step."""
        s_next, z = self(batch.s, batch.a, batch.v_prev, batch.z_prev[:, 0], batch.phi)
        _, fy0, _, b = self.material_response(batch.a[:, 0])
        fy = fy0 + b * batch.z[:, 0]
        return (((z[:, 0] - batch.z[:, 0]) / self.z_std[0]) ** 2).mean() \
            + (((fy - batch.z[:, 1]) / self.z_std[1]) ** 2).mean() \
            + (((s_next - batch.s_next) / self.s_std) ** 2).mean()
