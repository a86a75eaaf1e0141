"""What the control stage asks of a surrogate, as an adapter over the model's own step.

A model kind (deapull.surrogate.models) knows its training and its rollout, nothing of
control. The MPC's planner (:mod:`deapull.control.dynamics`), the online inference of φ
(:mod:`deapull.control.inference`) and the compiled path (:mod:`deapull.control.native`)
reach a model through :func:`adapter`, which wraps it in the adapter :data:`ADAPTERS` names for its
class (the nearest in its class hierarchy; a class without one offers nothing).

An adapter states its :data:`CAPABILITIES`:

* ``plan``: :meth:`Adapter.plan_step`, one step (s', z) for a planner; a kind whose step
  needs memory beyond the voltage before it lists the entries in :attr:`Adapter.plan_memory`
  and gives :meth:`Adapter.plan_start` and :meth:`Adapter.plan_step_memory` instead;
* ``infer``: x̂_{t+1}(φ) of buffered transitions, :meth:`Adapter.inference_columns` (what does
  not depend on φ, evaluated once) and :meth:`Adapter.predict_columns` (differentiable in φ);
  :meth:`Adapter.stick_shortfall` where the kind has a stick state;
* ``compiled_mpc`` / ``compiled_mpc_memory``: control/native.py runs the kind's step, its
  Jacobians and the iLQR in C (the tip-contact law, the tip-memory law).

A new kind plans and is inferred online once :data:`ADAPTERS` gives its class an adapter;
nothing else in control/ changes (tests/control/test_capabilities.py).
"""
from __future__ import annotations

import torch

from deapull.surrogate.models.memory import TipMemoryModel, tip_memory_step, tip_memory_step_scalar
from deapull.surrogate.models.paper import PhysicsModel
from deapull.surrogate.models.tip_contact import TipContactModel, TipPatchLagModel, regularised_slip
from deapull.surrogate.phi import Phi

#: what an adapter may offer the control stage (module docstring)
CAPABILITIES = ("plan", "infer", "compiled_mpc", "compiled_mpc_memory")


class Adapter:
    """A model kind without control hooks: it offers nothing."""

    capabilities: frozenset = frozenset()
    #: ``plan`` with memory: the entries a planner carries beside (x, u, V), as (name, unit) pairs
    #: (the unit scales the entry in the planner's state); empty for a kind whose memory is the
    #: voltage before the step alone
    plan_memory: tuple = ()

    def __init__(self, model):
        self.model = model

    def plan_step(self, s, a, v_prev, phi: Phi):
        """``plan``: one step (s', z) from the state, the action and the voltage ``v_prev`` before
        the step (a kind without memory of it ignores it)."""
        raise NotImplementedError(f"model kind {self.model.kind!r} cannot plan (capabilities: {sorted(self.capabilities) or 'nothing'})")

    def plan_start(self, V: torch.Tensor) -> torch.Tensor:
        """``plan`` with memory: the entries (..., len(plan_memory)) of the DEA at rest at ``V``, SI."""
        raise NotImplementedError(f"model kind {self.model.kind!r} has no planning memory")

    def plan_step_memory(self, s, a, v_prev, memory, phi: Phi):
        """``plan`` with memory: one step (s', z, memory') from the state, the action, the voltage
        before the step and the entries of :attr:`plan_memory` (SI units)."""
        raise NotImplementedError(f"model kind {self.model.kind!r} has no planning memory")

    def inference_columns(self, x_prev, x, V, V_next, dt, memory=None) -> dict:
        """``infer``: what x̂_{t+1}(φ) of buffered transitions needs that does not depend on φ: float64
        columns with at least ``s`` = (x, u) and ``a`` = (V', Δt), and whatever :meth:`predict_columns`
        uses. A kind with memory takes each row's entries before the transition (n, k), SI units, as
        ``memory`` (None: the DEA at rest at ``V``) and keeps them in the column ``memory``."""
        raise NotImplementedError(f"model kind {self.model.kind!r} cannot infer φ")

    def predict_columns(self, columns: dict, phi: Phi):
        """``infer``: x̂_{t+1} of the rows of :meth:`inference_columns` for the coin ``phi``."""
        raise NotImplementedError(f"model kind {self.model.kind!r} cannot infer φ")

    def stick_shortfall(self, columns: dict, phi: Phi):
        """``infer``: how far (m/s) each row the model holds stuck is from slipping, or None when the
        kind has no stick state."""
        return None

    def predict_with_shortfall(self, columns: dict, phi: Phi, shortfall: bool = True):
        """(:meth:`predict_columns`, :meth:`stick_shortfall` or None) together."""
        return self.predict_columns(columns, phi), (self.stick_shortfall(columns, phi) if shortfall else None)

    def memory_after(self, columns: dict, phi: Phi) -> torch.Tensor:
        """``infer`` with memory: the entries (n, k) after each row's transition, without gradients."""
        raise NotImplementedError(f"model kind {self.model.kind!r} has no memory to track")

    def memory_along(self, columns: dict, phi: Phi) -> torch.Tensor:
        """``infer`` with memory: the entries before each of consecutive rows, re-derived from the first."""
        raise NotImplementedError(f"model kind {self.model.kind!r} has no memory to track")


def _transition(x_prev, x, V_next, dt):
    """(s, a) of observed transitions: s = (x, (x − x_prev)/Δt), a = (V', Δt)."""
    return torch.stack([x, (x - x_prev) / dt], -1), torch.stack([V_next, dt], -1)


class PaperAdapter(Adapter):
    """The paper's f = d(m) (kind ``f``): the forces m(s, a) do not depend on φ."""

    capabilities = frozenset({"plan", "infer"})

    def plan_step(self, s, a, v_prev, phi: Phi):
        return self.model(s, a, phi)

    def inference_columns(self, x_prev, x, V, V_next, dt, memory=None) -> dict:
        s, a = _transition(x_prev, x, V_next, dt)
        with torch.no_grad():
            return {"s": s.double(), "a": a.double(), "z": self.model.forces(s, a).double()}

    def predict_columns(self, c: dict, phi: Phi):
        return self.model.dynamics(c["z"], c["s"], c["a"], phi)[..., 0]


class TipContactAdapter(Adapter):
    """The tip-contact law (kinds ``f-coulomb``, ``f-patch``): the material m(V) does not depend on φ,
    so a buffered row caches the stroke and the pressing force at its two voltages."""

    capabilities = frozenset({"plan", "infer", "compiled_mpc"})

    def plan_step(self, s, a, v_prev, phi: Phi):
        return self.model(s, a, v_prev, phi)

    def inference_columns(self, x_prev, x, V, V_next, dt, memory=None) -> dict:
        s, a = _transition(x_prev, x, V_next, dt)
        with torch.no_grad():
            stroke, fy, spread = self.model.material_all(torch.stack([V, V_next], -1))
        columns = {"s": s, "a": a, "stroke_prev": stroke[..., 0], "stroke": stroke[..., 1], "fy": fy[..., 1]}
        if spread is not None:
            columns["spread"] = spread[..., 1]
        return {k: v.double() for k, v in columns.items()}

    def predict_columns(self, c: dict, phi: Phi):
        return self.model.dynamics(c["s"], c["a"], c["stroke_prev"], c["stroke"], c["fy"], phi,
                                   c.get("spread"))[0][..., 0]

    def stick_shortfall(self, c: dict, phi: Phi):
        """(cap_b − |R|)⁺ Δt/m_c, with R the ground's reaction needed to hold the coin and cap_b =
        μ_b N its Coulomb limit; 0 where the model lets the coin slip."""
        m = self.model
        grip, spread = m.patch_at(c["s"][..., 0], c["stroke_prev"], c.get("spread"))
        phi = m._phi(phi, c["s"], torch.float64)
        dt, fy = c["a"][..., 1], c["fy"]
        w = (c["stroke"] - c["stroke_prev"]) / dt
        cap_t = phi.mu_t * torch.clamp(fy, min=0.0) * grip
        cap_b = phi.mu_b * torch.clamp(phi.mass_kg * m.gravity_m_s2 + fy, min=0.0)
        reaction = cap_t * regularised_slip(w, m.slip_eps(w, spread)) + phi.mass_kg / dt * c["s"][..., 1]
        return torch.relu(cap_b - reaction.abs()) * dt / phi.mass_kg


class TipPatchLagAdapter(TipContactAdapter):
    """``f-patch-lag``: the compiled path would need the lag's terms in x, so torch only."""

    capabilities = frozenset({"plan", "infer"})


class TipMemoryAdapter(Adapter):
    """The tip-memory law (kind ``f-memory``). The planner's state carries the tip's contact point
    P (m) and friction T (N) of the previous step beside (x, u, V). A transition's prediction needs
    (P, T) before it, which depends on φ through the whole history: the inference carries them
    along its buffer by the model's own step under its current estimate of φ (as the MPC policy
    tracks them), re-derives them along the buffer as the estimate moves, and fits φ through one
    step per row with (P, T) given."""

    capabilities = frozenset({"plan", "infer", "compiled_mpc_memory"})
    plan_memory = (("P", 1e-3), ("T", 1e-2))

    def plan_start(self, V: torch.Tensor) -> torch.Tensor:
        """(P, T) of the DEA at rest at ``V`` without friction: P = X(V), T = 0 (as the rollout's
        first step)."""
        return self.model.rest_memory(V)[..., 1:]

    def plan_step(self, s, a, v_prev, phi: Phi):
        raise NotImplementedError("f-memory plans with its memory: plan_step_memory (plan_memory)")

    def plan_step_memory(self, s, a, v_prev, memory, phi: Phi):
        """One step (s', z, (P', T')) from (x, u), (V', Δt), V and (P, T); differentiable in all of
        them (implicit gradients of the step's root, :func:`tip_memory_step`)."""
        full = torch.cat([v_prev.unsqueeze(-1), memory], dim=-1)
        s_next, z, full_next = self.model.dynamics(s, a, full, phi)
        return s_next, z, full_next[..., 1:]

    def inference_columns(self, x_prev, x, V, V_next, dt, memory=None) -> dict:
        m = self.model
        s, a = _transition(x_prev, x, V_next, dt)
        with torch.no_grad():
            if memory is None:
                memory = self.plan_start(V.to(m.in_mean.dtype))
            stroke, fy0, compliance, b = m.material_response(V_next.to(m.in_mean.dtype))
        columns = {"s": s, "a": a, "memory": memory, "stroke": stroke, "fy0": fy0, "compliance": compliance, "b": b}
        return {k: v.double() for k, v in columns.items()}

    def _columns_step(self, c: dict, phi: Phi):
        m = self.model
        phi = m._phi(phi, c["s"], torch.float64)
        return tip_memory_step(c["s"][..., 1], c["memory"][..., 0], c["stroke"], c["compliance"], c["fy0"], c["b"],
                               phi.mu_t, phi.mu_b, phi.mass_kg, c["a"][..., 1], m.gravity_m_s2,
                               m.slip_rate_reg_m_s, m.iterations, c["memory"][..., 1])

    def predict_columns(self, c: dict, phi: Phi):
        return self.predict_with_shortfall(c, phi, shortfall=False)[0]

    def stick_shortfall(self, c: dict, phi: Phi):
        """(μ_b N − |R|)⁺ Δt/m_c at the step's tip friction T', with R = T' + m_c u/Δt the ground's
        reaction needed to hold the coin; 0 where the model lets the coin slip."""
        return self.predict_with_shortfall(c, phi)[1]

    def predict_with_shortfall(self, c: dict, phi: Phi, shortfall: bool = True):
        """Both from one solve of the step (the solve is the cost)."""
        u_next, T, fy, _ = self._columns_step(c, phi)
        dt = c["a"][..., 1]
        x_next = c["s"][..., 0] + dt * u_next
        if not shortfall:
            return x_next, None
        phi = self.model._phi(phi, c["s"], torch.float64)
        cap = phi.mu_b * torch.clamp(phi.mass_kg * self.model.gravity_m_s2 + fy, min=0.0)
        reaction = T + phi.mass_kg / dt * c["s"][..., 1]
        stuck = (u_next == 0).double()
        return x_next, stuck * torch.relu(cap - reaction.abs()) * dt / phi.mass_kg

    @torch.no_grad()
    def memory_after(self, c: dict, phi: Phi) -> torch.Tensor:
        _, T, _, P_next = self._columns_step(c, phi)
        return torch.stack([P_next, T], dim=-1)

    @torch.no_grad()
    def memory_along(self, c: dict, phi: Phi) -> torch.Tensor:
        """Row 0's memory as given, each next one :meth:`memory_after` the row before (Python floats,
        :func:`tip_memory_step_scalar`: a sequential scan)."""
        m = self.model
        mass, mu_b, mu_t = (phi.value(f) for f in ("mass_kg", "mu_b", "mu_t"))
        u, dt = c["s"][:, 1].tolist(), c["a"][:, 1].tolist()
        cols = [c[k].tolist() for k in ("stroke", "compliance", "fy0", "b")]
        out = c["memory"].clone()
        P, T = (float(v) for v in out[0])
        for i in range(out.shape[0] - 1):
            _, T, _, P = tip_memory_step_scalar(u[i], P, cols[0][i], cols[1][i], cols[2][i], cols[3][i], mu_t, mu_b,
                                                mass, dt[i], m.gravity_m_s2, m.slip_rate_reg_m_s, m.iterations, T)
            out[i + 1, 0], out[i + 1, 1] = P, T
        return out


#: model class -> its adapter; a model takes the adapter of the nearest class in its hierarchy
ADAPTERS: dict[type, type[Adapter]] = {
    PhysicsModel: PaperAdapter,
    TipContactModel: TipContactAdapter,
    TipPatchLagModel: TipPatchLagAdapter,
    TipMemoryModel: TipMemoryAdapter,
}


def adapter_class(model_cls: type) -> type[Adapter]:
    """The adapter of ``model_cls``: that of the nearest class in its MRO, else :class:`Adapter`."""
    for cls in model_cls.__mro__:
        if cls in ADAPTERS:
            return ADAPTERS[cls]
    return Adapter


def adapter(model) -> Adapter:
    """``model`` wrapped in its kind's adapter."""
    return adapter_class(type(model))(model)


def capabilities(model_or_cls) -> frozenset:
    """What the control stage may ask of a model (or a model class)."""
    cls = model_or_cls if isinstance(model_or_cls, type) else type(model_or_cls)
    return adapter_class(cls).capabilities
