"""f_a as the MPC sees it: the coin task's dynamics in scaled units and its cost.

Below both the MPC policy (:mod:`deapull.control.mpc_policy`) and the compiled twin
(:mod:`deapull.control.native`), which share these units and :class:`CoinDynamics`.

**State and control** (scaled so that every entry is O(0.01–1)):
ξ = (x / 1 mm, u / (0.01 m/s), V / 100 V), the coin's position and velocity and the
voltage now applied (the DEA's state: the tip-contact model's memory is its stroke at that
voltage); control ν = ΔV / ΔV_max ∈ [−1, 1] (the env's per-step limit). One step:
V' = clip(V + ν ΔV_max, 0, V_max) (the env's own clipping, so V ∈ [0, V_max] holds in the
plan as in the env), then (x', u') = f_a((x, u), (V', Δt); V, φ) with the current φ.

**Memory.** A kind whose step needs more than the voltage before it (``f-memory``: the tip's
contact point P and friction T of the previous step, :attr:`~deapull.control.adapters.Adapter.plan_memory`) has
them appended to ξ in their own units (P / 1 mm, T / 0.01 N), carried through the rollout
and differentiated like the rest: ξ = (x, u, V, P, T). The cost ignores them.

**Costs** (:func:`coin_cost`), ℓ_t on (ξ_t, ν_t) and ℓ_T on ξ_T:

* ``scaled`` (default): ½[(x − x^T)²/mm² + w ν²] with w = ``dv_weight`` (1e-3: a full
  ΔV_max step costs as much as a 0.032 mm error held for one step), and the same position
  term at the end. No cost on V itself: holding the coin at the target may need a high
  steady voltage.
* ``paper``: the paper's ½[(x − x^T)² + 10⁻³ V²] in SI units (eq. 8, w_s = 1,
  w_a = 10⁻³ on the voltage), rescaled by 10⁶ (same minimiser). At V ≈ 370 V the voltage
  term is ~10⁸ times the position term at a 1 mm error, so this MPC keeps V near 0.
"""
from __future__ import annotations

import copy

import torch

from deapull.control import mpc
from deapull.control.adapters import adapter, capabilities
from deapull.errors import InputError
from deapull.surrogate.phi import Phi

#: units of the scaled state (x in m, u in m/s, V in V)
X_UNIT_M, U_UNIT_M_S, V_UNIT_V = 1e-3, 1e-2, 100.0
COSTS = ("scaled", "paper")
#: the paper's action penalty on V (eq. 8, with w_s = 1 on x in m)
PAPER_ACTION_WEIGHT = 1e-3


class CoinDynamics:
    """f_a as ``dynamics(ξ (N, 3), ν (N, 1)) -> ξ' (N, 3)`` in scaled units (module docstring).

    Parameters
    ----------
    model : Surrogate
        f_a, kind ``f-coulomb`` or ``f``; a float64 copy with frozen weights is used.
    phi : Phi
        The coin to plan for (:attr:`phi` may be replaced between solves).
    dt, dv_max_V, v_max_V : float
        Step (s), per-step limit of |ΔV| (V) and largest voltage (V).
    """

    def __init__(self, model, phi: Phi, dt: float, dv_max_V: float, v_max_V: float):
        if "plan" not in capabilities(model):
            raise InputError(f"the MPC plans with a model that can plan (capability 'plan'); {model.kind!r} "
                             f"offers {sorted(capabilities(model)) or 'nothing'}")
        self.model = copy.deepcopy(model).double().eval().requires_grad_(False)
        self.adapter = adapter(self.model)
        self.phi = phi
        self.dt, self.dv_max_V, self.v_max_V = float(dt), float(dv_max_V), float(v_max_V)
        #: units of the memory entries appended to ξ (empty: ξ = (x, u, V))
        self.memory_units = torch.tensor([unit for _, unit in self.adapter.plan_memory], dtype=torch.float64)
        self.n = 3 + len(self.memory_units)

    def __call__(self, xi: torch.Tensor, nu: torch.Tensor) -> torch.Tensor:
        x, u, V = xi[:, 0] * X_UNIT_M, xi[:, 1] * U_UNIT_M_S, xi[:, 2] * V_UNIT_V
        V_next = torch.clamp(V + nu[:, 0] * self.dv_max_V, 0.0, self.v_max_V)
        s = torch.stack([x, u], -1)
        a = torch.stack([V_next, torch.full_like(V_next, self.dt)], -1)
        if self.n == 3:
            s_next, _ = self.adapter.plan_step(s, a, V, self.phi)
            tail = ()
        else:
            s_next, _, memory = self.adapter.plan_step_memory(s, a, V, xi[:, 3:] * self.memory_units, self.phi)
            tail = (memory / self.memory_units).unbind(-1)
        return torch.stack([s_next[:, 0] / X_UNIT_M, s_next[:, 1] / U_UNIT_M_S, V_next / V_UNIT_V, *tail], -1)

    def state(self, x_m: float, u_m_s: float, V_V: float, memory=None) -> torch.Tensor:
        """ξ (1, n) of a coin at x (m) with velocity u (m/s) under V (V); with memory entries
        (:attr:`memory_units`), ``memory`` holds them in scaled units (a ξ[3:] of an earlier
        step), or None: the DEA at rest at V."""
        xi = torch.tensor([[x_m / X_UNIT_M, u_m_s / U_UNIT_M_S, V_V / V_UNIT_V]], dtype=torch.float64)
        if self.n == 3:
            return xi
        if memory is None:
            with torch.no_grad():
                memory = self.adapter.plan_start(torch.tensor([V_V], dtype=torch.float64)) / self.memory_units
        return torch.cat([xi, torch.as_tensor(memory, dtype=torch.float64).reshape(1, -1)], -1)


def coin_cost(target_m: float, kind: str = "scaled", dv_weight: float = 1e-3, terminal_weight: float = 1.0,
              memory: int = 0) -> mpc.QuadCost:
    """The MPC's cost on (ξ, ν) (module docstring); constant terms dropped. ``memory``: the
    number of memory entries appended to ξ (no cost on them)."""
    if kind not in COSTS:
        raise InputError(f"MPC cost {kind!r}: choose one of {', '.join(COSTS)}")
    xt = target_m / X_UNIT_M
    if kind == "scaled":
        w_x, w_V, w_dv = 1.0, 0.0, float(dv_weight)
    else:
        # ½[(x − x^T)² + 1e-3 V²] (SI) × 1e6, in ξ: x = 1e-3 ξ_0, V = 100 ξ_2
        w_x, w_V, w_dv = 1.0, PAPER_ACTION_WEIGHT * V_UNIT_V ** 2 / X_UNIT_M ** 2, 0.0
    pad = [0.0] * memory
    C = torch.diag(torch.tensor([w_x, 0.0, w_V, *pad, w_dv], dtype=torch.float64))
    c = torch.tensor([-w_x * xt, 0.0, 0.0, *pad, 0.0], dtype=torch.float64)
    n = 3 + memory
    return mpc.QuadCost(C, c, terminal_weight * C[:n, :n].clone(), terminal_weight * c[:n].clone())
