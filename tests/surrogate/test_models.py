"""The dynamics laws and f = d∘m: physics, and gradients against finite differences."""
from __future__ import annotations

import math

import pytest
import torch

from surrogate.data import transitions
from surrogate.models import (InputRange, Normalisation, PhysicsModel, build, coulomb_dynamics,
                              friction_release, paper_dynamics)

G = 9.8


def test_coulomb_law_reproduces_the_fem_coin(sweep):
    """Fed the dataset's own forces, the Coulomb law gives the dataset's next states: the
    velocity to round-off, the position to the FEM's coin-coupling tolerance."""
    data = sweep["C5"]
    coupling_tol = 2e-10     # solver.coupling_tol_m = 1e-10: the FEM stores the converged iterate
    tr = transitions([data], 1, dtype=torch.float64)
    exact = coulomb_dynamics(tr.z, tr.s, tr.a, data.coin_mass_kg, data.mu_b, G, smoothing=0.0)
    assert torch.allclose(exact[:, 1], tr.s_next[:, 1], rtol=0, atol=1e-12)
    assert torch.allclose(exact[:, 0], tr.s_next[:, 0], rtol=0, atol=coupling_tol)
    tau = 1e-6
    smooth = coulomb_dynamics(tr.z, tr.s, tr.a, data.coin_mass_kg, data.mu_b, G, smoothing=tau)
    assert (smooth[:, 1] - tr.s_next[:, 1]).abs().max() <= tau * math.log(2)
    assert (smooth[:, 0] - tr.s_next[:, 0]).abs().max() <= tau * math.log(2) * tr.a[:, 1].max() + coupling_tol


@pytest.mark.parametrize("law", ["paper", "coulomb"])
def test_forces_inside_the_friction_bound_keep_the_coin_still(law):
    gen = torch.Generator().manual_seed(0)
    n, mass, mu_b, vt = 1000, 1.36e-3, 0.2, 150.0
    V = torch.rand(n, generator=gen, dtype=torch.float64) * vt
    fy = 4e-3 + 0.03 * torch.rand(n, generator=gen, dtype=torch.float64)
    bound = mu_b * (mass * G + fy) * (V / vt if law == "paper" else 1.0)
    fx = -0.99 * bound * torch.rand(n, generator=gen, dtype=torch.float64)
    s = torch.zeros(n, 2, dtype=torch.float64)
    a = torch.stack([V, torch.full_like(V, 1e-3)], 1)
    z = torch.stack([fx, fy], 1)
    if law == "paper":
        out = paper_dynamics(z, s, a, mass, mu_b, G, vt, math.inf)
    else:
        out = coulomb_dynamics(z, s, a, mass, mu_b, G, smoothing=1e-6)
    assert out.abs().max() < 1e-12


def test_friction_decays_a_moving_coin_without_reversing_it():
    u = torch.tensor([-2e-3, -1e-5, 0.0, 3e-3], dtype=torch.float64)
    cap = torch.full_like(u, 1e-4)
    assert friction_release(u, cap, 0.0).tolist() == pytest.approx([-1.9e-3, 0.0, 0.0, 2.9e-3])
    smooth = friction_release(u, cap, 1e-6)
    assert smooth[2] == 0 and smooth[1].abs() < 1e-12
    assert smooth.tolist() == pytest.approx([-1.9e-3, 0.0, 0.0, 2.9e-3], abs=1e-9)


def test_paper_law_contact_loss_and_switch_off():
    """Above the contact-loss voltage the DEA no longer drives; at V = 0 the coin slows at μ_b g."""
    s = torch.tensor([[0.0, -1e-3]], dtype=torch.float64)
    z = torch.tensor([[-0.02, 0.01]], dtype=torch.float64)
    mass, mu_b, dt = 1.36e-3, 0.2, 1e-4
    lost = paper_dynamics(z, s, torch.tensor([[350.0, dt]], dtype=torch.float64), mass, mu_b, G, 150.0, 300.0)
    off = paper_dynamics(z, s, torch.tensor([[0.0, dt]], dtype=torch.float64), mass, mu_b, G, 150.0, 300.0)
    assert lost[0, 1].item() == pytest.approx(-1e-3 + dt * mu_b * G)
    assert off[0, 1].item() == pytest.approx(-1e-3 + dt * mu_b * (mass * G + 0.01) / mass)


def _model(sweep, law: str) -> PhysicsModel:
    tr = transitions([sweep["C1"]], 1)
    torch.manual_seed(0)
    model = PhysicsModel(Normalisation.from_transitions(tr), InputRange.from_transitions(tr), law=law,
                         smoothing_m_s=1e-4).double()
    model.set_setup(1.36e-3, 0.2, 150.0)
    return model


@pytest.mark.parametrize("law", ["paper", "coulomb"])
def test_gradients_wrt_phi_match_finite_differences(sweep, law):
    model = _model(sweep, law)
    s = torch.tensor([[-2e-4, -1.2e-3], [-5e-4, -2e-3], [0.0, 0.0]], dtype=torch.float64)
    a = torch.tensor([[180.0, 1e-3], [120.0, 1.3e-3], [250.0, 8e-4]], dtype=torch.float64)
    model.mass_kg.requires_grad_(True)
    model.mu_b.requires_grad_(True)
    out, _ = model(s, a)
    weights = torch.tensor([[1e3, 1.0], [2e3, -1.0], [5e2, 3.0]], dtype=torch.float64)
    (out * weights).sum().backward()
    for p in (model.mass_kg, model.mu_b):
        h = 1e-6 * p.item()
        with torch.no_grad():
            p += h
            up = (model(s, a)[0] * weights).sum().item()
            p -= 2 * h
            down = (model(s, a)[0] * weights).sum().item()
            p += h
        assert p.grad.item() == pytest.approx((up - down) / (2 * h), rel=1e-5)
        assert p.grad.item() != 0


@pytest.mark.parametrize("law", ["paper", "coulomb"])
def test_f_is_differentiable_in_state_action_and_weights(sweep, law):
    model = _model(sweep, law)
    s = torch.tensor([[-2e-4, -1.2e-3]], dtype=torch.float64, requires_grad=True)
    a = torch.tensor([[180.0, 1e-3]], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda s, a: model(s, a)[0], (s, a), eps=1e-9, atol=1e-7, rtol=1e-4)
    model(s, a)[0].sum().backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in model.material.parameters())


def test_build_rejects_unknown_kind(sweep):
    tr = transitions([sweep["C1"]], 1)
    with pytest.raises(ValueError, match="unknown model kind"):
        build("gp", Normalisation.from_transitions(tr), InputRange.from_transitions(tr))
