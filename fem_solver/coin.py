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


def coulomb_step(state: CoinState, Fx: float, Fy: float, dt: float, mass: float, mu_b: float,
                 g: float) -> CoinState:
    """Advance the coin by ``dt`` under the DEA's force (Fx, Fy) and ground friction."""
    normal = max(mass * g + Fy, 0.0)
    trial = mass * state.u + dt * Fx
    cap = dt * mu_b * normal
    if abs(trial) <= cap:
        return CoinState(state.x, 0.0, True)
    u = (trial - math.copysign(cap, trial)) / mass
    return CoinState(state.x + dt * u, u, False)


def force_balance_residual(prev: CoinState, new: CoinState, Fx: float, Fy: float, dt: float, mass: float,
                           mu_b: float, g: float) -> float:
    """|m (u − u_n)/Δt − Fx + f_b| with f_b the Coulomb friction the step used (N); 0 when exact."""
    normal = max(mass * g + Fy, 0.0)
    inertia = mass * (new.u - prev.u) / dt
    if new.stick:
        friction = Fx - inertia  # static friction takes whatever balances, if within the cone
        return max(abs(friction) - mu_b * normal, 0.0)
    return abs(inertia - Fx + math.copysign(mu_b * normal, new.u))
