"""control/ reaches a model through the adapter registered for its class, never by its kind's
name: a new kind and its adapter, registered here in the test, plan through the MPC and are
inferred online without a line of control/ changing; a kind that lacks a capability is refused
naming it, and the model class itself carries no control hook."""
from __future__ import annotations

import pytest
import torch

from deapull.control.dynamics import CoinDynamics, coin_cost
from deapull.control.inference import InferenceConfig, OnlineInference
from deapull.control.mpc_policy import make_dynamics
from deapull.control import adapters, mpc
from deapull.errors import InputError
from deapull.surrogate.models import registry
from deapull.surrogate.models.base import InputRange, Normalisation, Surrogate
from deapull.surrogate.phi import Phi

F64 = torch.float64


class Viscous(Surrogate):
    """A toy coin: pushed at gain k per volt above its last voltage, damped by the ground:
    u' = k max(V' − V, 0) / (m_c μ_b), x' = x + Δt u'."""
    kind = "toy-viscous"
    label = "toy"
    physics = True
    phi_fields = ("mass_kg", "mu_b")
    gain = 1e-6

    def forward(self, s, a, v_prev, phi):
        phi = phi.to(dtype=s.dtype)
        u = self.gain * torch.relu(a[..., 0] - v_prev) / (phi.mass_kg * phi.mu_b)
        return torch.stack([s[..., 0] + a[..., 1] * u, u], -1), None


class ViscousAdapter(adapters.Adapter):
    """What control/ asks of the toy: its step, and the push that x̂_{t+1}(φ) needs."""
    capabilities = frozenset({"plan", "infer"})

    def plan_step(self, s, a, v_prev, phi):
        return self.model(s, a, v_prev, phi)

    def inference_columns(self, x_prev, x, V, V_next, dt, memory=None):
        s, a = torch.stack([x, (x - x_prev) / dt], -1), torch.stack([V_next, dt], -1)
        return {"s": s.double(), "a": a.double(), "push": torch.relu(V_next - V).double()}

    def predict_columns(self, c, phi):
        m = self.model
        return c["s"][..., 0] + c["a"][..., 1] * m.gain * c["push"] / (phi.mass_kg * phi.mu_b)


@pytest.fixture
def toy(monkeypatch):
    monkeypatch.setitem(registry.KINDS, Viscous.kind, Viscous)      # the registry and the adapter are all
    monkeypatch.setitem(adapters.ADAPTERS, Viscous, ViscousAdapter)  # a kind touches
    norm = Normalisation.__new__(Normalisation)
    model = Viscous.__new__(Viscous)
    torch.nn.Module.__init__(model)
    model.norm, model.input_range, model.hparams = norm, InputRange.__new__(InputRange), {}
    return model


def test_a_new_kind_plans_through_the_mpc_by_its_capabilities(toy):
    phi = Phi(mass_kg=1.0e-3, mu_b=0.2).to(dtype=F64)
    dyn = make_dynamics(toy, phi, 1e-3, 5.0, 400.0, engine="auto")
    assert type(dyn) is CoinDynamics                          # no compiled MPC for this kind
    x0 = dyn.state(0.0, 0.0, 100.0)
    start = torch.full((1, 20, 1), 0.5, dtype=F64)
    sol = mpc.solve(dyn, coin_cost(-0.1e-3), x0, start, -1.0, 1.0, iterations=10)
    x_end = float(mpc.rollout(dyn, x0, sol.u)[0, -1, 0]) * 1e-3
    x_start = float(mpc.rollout(dyn, x0, start)[0, -1, 0]) * 1e-3
    assert abs(x_end + 0.1e-3) < abs(x_start + 0.1e-3)        # the plan moves the coin toward the target
    with pytest.raises(InputError, match="the native MPC needs"):
        make_dynamics(toy, phi, 1e-3, 5.0, 400.0, engine="native")


def test_a_new_kind_is_inferred_online_by_its_capabilities(toy):
    truth = Phi(mass_kg=2.0e-3, mu_b=0.25).to(dtype=F64)
    inf = OnlineInference(toy, InferenceConfig(optimizer="lm", fields=("mass_kg",), batch_size=64,
                                               initial={"mass_kg": 1e-3, "mu_b": 0.25}), dt=1e-3)
    x, V = 0.0, 0.0
    inf.observe(x, V)
    for k in range(200):
        V_next = V + (5.0 if k % 3 else 0.0)
        x = float(toy(torch.tensor([[x, 0.0]], dtype=F64), torch.tensor([[V_next, 1e-3]], dtype=F64),
                      torch.tensor([V], dtype=F64), truth)[0][0, 0])
        V = V_next
        inf.observe(x, V)
        inf.update()
    assert float(inf.phi.mass_kg) == pytest.approx(2.0e-3, rel=1e-3)


def test_a_kind_without_a_capability_is_refused_naming_it(toy, monkeypatch):
    monkeypatch.setattr(ViscousAdapter, "capabilities", frozenset())
    with pytest.raises(InputError, match="capability 'plan'"):
        CoinDynamics(toy, Phi(mass_kg=1e-3, mu_b=0.2), 1e-3, 5.0, 400.0)
    with pytest.raises(InputError, match="capability 'infer'"):
        OnlineInference(toy, InferenceConfig(initial={"mass_kg": 1e-3, "mu_b": 0.2}), dt=1e-3)


def test_the_models_carry_no_control_hooks():
    """Planning and inference live in control/adapters.py: no registered kind defines them."""
    from deapull.surrogate.models import registry as kinds
    hooks = ("plan_step", "plan_start", "plan_step_memory", "inference_columns", "predict_columns",
             "stick_shortfall", "predict_with_shortfall", "memory_after", "memory_along", "capabilities", "can")
    for kind, cls in kinds.KINDS.items():
        assert not [h for h in hooks if hasattr(cls, h)], kind
    assert {kind: sorted(adapters.capabilities(cls)) for kind, cls in kinds.KINDS.items()} == {
        "f": ["infer", "plan"], "f-coulomb": ["compiled_mpc", "infer", "plan"],
        "f-patch": ["compiled_mpc", "infer", "plan"], "f-patch-lag": ["infer", "plan"],
        "f-memory": ["compiled_mpc_memory", "infer", "plan"], "nn": [], "lstm": []}
