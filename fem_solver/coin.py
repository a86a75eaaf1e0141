"""The coin: a rigid body sliding along x with Coulomb stick/slip on the ground.

Implicit (backward Euler) momentum step with a Coulomb friction impulse::

    trial momentum   q* = m u_n + Δt Fx
    friction cap     c  = Δt μ_b N,       N = m g + Fy  (≥ 0)
    stick            |q*| ≤ c  →  u = 0
    slip             u = (q* − sign(q*) c) / m
    position         x = x_n + Δt u

so the coin starts to slide when |Fx| exceeds μ_b N and then follows
m a = Fx − μ_b N sign(u); with Fx = 0 a moving coin decelerates at μ_b g and stops.
"""
from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class CoinState:
    x: float = 0.0       # displacement along x (m)
    u: float = 0.0       # velocity along x (m/s)
    stick: bool = True


def coulomb_step(state: CoinState, Fx: float, Fy: float, dt: float, mass_kg: float, mu_b: float,
                 g: float) -> CoinState:
    """Advance the coin by ``dt`` under the DEA's force (Fx, Fy) and ground friction."""
    normal = max(mass_kg * g + Fy, 0.0)
    trial = mass_kg * state.u + dt * Fx
    cap = dt * mu_b * normal
    if abs(trial) <= cap:
        return CoinState(state.x, 0.0, True)
    u = (trial - math.copysign(cap, trial)) / mass_kg
    return CoinState(state.x + dt * u, u, False)


def force_balance_residual(prev: CoinState, new: CoinState, Fx: float, Fy: float, dt: float, mass_kg: float,
                           mu_b: float, g: float) -> float:
    """The coin's momentum balance over a step from ``prev`` to ``new`` under the force
    (Fx, Fy) of the DEA (N); 0 when the balance holds::

        slip    | m (u − u_n)/Δt − Fx + μ_b N sign(u) |,          N = max(m g + Fy, 0)
        stick   max(| Fx − m (u − u_n)/Δt | − μ_b N, 0)      (static friction within the cone)

    ``dt = 0`` (the placement, no step) checks the static cone without inertia. Fed the same
    (Fx, Fy) that :func:`coulomb_step` used, it is zero by construction; the stepper feeds
    it the DEA's force from the clamp reaction (``DEAProblem.obstacle_forces_from_reaction``),
    which does not pass through the contact integral the coupling uses.
    """
    normal = max(mass_kg * g + Fy, 0.0)
    inertia = mass_kg * (new.u - prev.u) / dt if dt > 0 else 0.0
    if new.stick:
        friction = Fx - inertia  # static friction takes whatever balances, if within the cone
        return max(abs(friction) - mu_b * normal, 0.0)
    return abs(inertia - Fx + math.copysign(mu_b * normal, new.u))
