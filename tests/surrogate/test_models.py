"""The dynamics laws and f = d∘m: physics against analytic solutions, and gradients against
finite differences."""
from __future__ import annotations

import copy
import math

import numpy as np
import pytest
import torch

from surrogate.data import transitions
from surrogate.models import (InputRange, Normalisation, PhysicsModel, build, paper_dynamics, regularised_slip,
                              tip_coin_step)

G = 9.8
MASS, EPS = 1.36e-3, 1e-4


def test_paper_law_forces_inside_the_ramped_bound_keep_the_coin_still():
    gen = torch.Generator().manual_seed(0)
    n, mu_b, vt = 1000, 0.2, 150.0
    V = torch.rand(n, generator=gen, dtype=torch.float64) * vt
    fy = 4e-3 + 0.03 * torch.rand(n, generator=gen, dtype=torch.float64)
    bound = mu_b * (MASS * G + fy) * V / vt
    fx = -0.99 * bound * torch.rand(n, generator=gen, dtype=torch.float64)
    s = torch.zeros(n, 2, dtype=torch.float64)
    a = torch.stack([V, torch.full_like(V, 1e-3)], 1)
    out = paper_dynamics(torch.stack([fx, fy], 1), s, a, MASS, mu_b, G, vt, math.inf)
    assert out.abs().max() < 1e-12


def test_paper_law_contact_loss_and_switch_off():
    """Above the contact-loss voltage the DEA no longer drives; at V = 0 the coin slows at μ_b g."""
    s = torch.tensor([[0.0, -1e-3]], dtype=torch.float64)
    z = torch.tensor([[-0.02, 0.01]], dtype=torch.float64)
    mu_b, dt = 0.2, 1e-4
    lost = paper_dynamics(z, s, torch.tensor([[350.0, dt]], dtype=torch.float64), MASS, mu_b, G, 150.0, 300.0)
    off = paper_dynamics(z, s, torch.tensor([[0.0, dt]], dtype=torch.float64), MASS, mu_b, G, 150.0, 300.0)
    assert lost[0, 1].item() == pytest.approx(-1e-3 + dt * mu_b * G)
    assert off[0, 1].item() == pytest.approx(-1e-3 + dt * mu_b * (MASS * G + 0.01) / MASS)


def _random_contacts(n: int, seed: int):
    gen = torch.Generator().manual_seed(seed)
    rand = lambda: torch.rand(n, generator=gen, dtype=torch.float64)  # noqa: E731
    u = -3e-3 * rand() * (rand() < 0.7)
    w = -5e-3 * rand() + 1e-3 * (rand() - 0.5)
    fy = 2e-3 + 0.04 * rand()
    mu_t, mu_b = 0.3 + 0.4 * rand(), 0.1 + 0.3 * rand()
    return u, w, mu_t * fy, mu_b * (MASS * G + fy)


def test_tip_step_solves_the_backward_euler_coin_equation():
    """Every returned step satisfies m_c (u' - u)/Δt = T(u') - B with B in the ground's cone:
    B = μ_b N sgn(u') when sliding, |B| ≤ μ_b N when stuck; T is the FEM's regularised law."""
    u, w, cap_t, cap_b = _random_contacts(4000, 1)
    dt = 1e-3
    u_next, force = tip_coin_step(u, w, cap_t, cap_b, MASS, dt, EPS)
    ground = force - MASS * (u_next - u) / dt
    moving = u_next != 0
    assert 0.2 < moving.double().mean() < 0.95, "both regimes are exercised"
    assert torch.allclose(force, cap_t * regularised_slip(w - u_next, EPS), rtol=1e-12, atol=1e-15)
    assert torch.allclose(ground[moving], cap_b[moving] * torch.sign(u_next[moving]), rtol=1e-9, atol=1e-13)
    assert (ground[~moving].abs() <= cap_b[~moving] * (1 + 1e-12)).all()


def test_tip_step_onset_follows_the_friction_cones():
    """A coin at rest starts to move exactly when the tip's friction μ_t Fy ε-regularised at the
    tip's speed exceeds the ground's μ_b N: both sides of the threshold, to 1e-9."""
    fy = torch.full((2,), 0.01, dtype=torch.float64)
    w = torch.full((2,), -1e-3, dtype=torch.float64)
    pull = 0.5 * fy * regularised_slip(w, EPS).abs()
    cap_b = pull * torch.tensor([1 + 1e-9, 1 - 1e-9], dtype=torch.float64)
    u_next, _ = tip_coin_step(torch.zeros(2, dtype=torch.float64), w, 0.5 * fy, cap_b, MASS, 1e-3, EPS)
    assert u_next[0] == 0 and u_next[1] < 0


def test_tip_step_reaches_the_analytic_steady_lag():
    """Dragged by a tip at constant speed, the coin settles where the regularised friction
    balances the ground: w - u = ε r/√(1 - r²), r = μ_b N/(μ_t Fy)."""
    w, fy, mu_t, mu_b, dt = -2e-3, 0.02, 0.55, 0.2, 1e-3
    normal = MASS * G + fy
    u = torch.zeros(1, dtype=torch.float64)
    for _ in range(400):
        u, _ = tip_coin_step(u, torch.full_like(u, w), torch.full_like(u, mu_t * fy),
                             torch.full_like(u, mu_b * normal), MASS, dt, EPS)
    r = mu_b * normal / (mu_t * fy)
    assert u.item() == pytest.approx(w + EPS * r / math.sqrt(1 - r * r), rel=1e-9)


def test_tip_step_released_coin_decelerates_at_the_coulomb_rate():
    """With the tip at rest and no pressing force the coin slides to a stop under μ_b g
    alone: v(t) = v0 - μ_b g t, stopping at v0/(μ_b g) and staying there."""
    mu_b, dt, v0 = 0.25, 1e-4, -2e-3
    u, speeds = torch.tensor([v0], dtype=torch.float64), []
    zero = torch.zeros(1, dtype=torch.float64)
    for _ in range(30):
        u, _ = tip_coin_step(u, zero, zero, torch.full_like(u, mu_b * MASS * G), MASS, dt, EPS)
        speeds.append(u.item())
    expected = np.minimum(v0 + mu_b * G * dt * np.arange(1, 31), 0.0)
    assert np.allclose(speeds, expected, rtol=0, atol=1e-15)


@pytest.fixture
def tip_model(trained):
    model = copy.deepcopy(trained("f-coulomb").model).double()
    model.set_setup(1.36e-3, 0.2, mu_t=0.5)
    return model


def _sliding_rows(sweep):
    data = sweep["C1"]
    tr = transitions([data], 1, dtype=torch.float64)
    sliding = torch.nonzero(tr.s[:, 1] < -1e-4).flatten()
    assert len(sliding) > 100, "the coin slides in the test sweep"
    idx = sliding[torch.tensor([len(sliding) // 4, len(sliding) // 2, 3 * len(sliding) // 4])]
    return tr.s[idx], tr.a[idx], tr.v_prev[idx]


def test_tip_model_gradients_wrt_phi_match_finite_differences(sweep, tip_model):
    s, a, v_prev = _sliding_rows(sweep)
    params = (tip_model.mass_kg, tip_model.mu_b, tip_model.mu_t)
    for p in params:
        p.requires_grad_(True)
    weights = torch.tensor([[1e3, 1.0], [2e3, -1.0], [5e2, 3.0]], dtype=torch.float64)
    out, z = tip_model(s, a, v_prev)
    assert (out[:, 1] != 0).all(), "the coin slides in these rows"
    ((out * weights).sum() + 10 * z[:, 0].sum()).backward()
    for p in params:
        h = 1e-6 * p.item()
        values = []
        for sign in (1, -1):
            with torch.no_grad():
                p += sign * h
                o, zz = tip_model(s, a, v_prev)
                values.append(((o * weights).sum() + 10 * zz[:, 0].sum()).item())
                p -= sign * h
        assert p.grad.item() == pytest.approx((values[0] - values[1]) / (2 * h), rel=1e-5)
        assert p.grad.item() != 0


def test_tip_model_is_differentiable_in_state_action_and_weights(sweep, tip_model):
    s, a, v_prev = _sliding_rows(sweep)
    s, a = s[:1].clone().requires_grad_(True), a[:1].clone().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda s, a: tip_model(s, a, v_prev[:1])[0], (s, a), eps=1e-9, atol=1e-7,
                                    rtol=1e-4)
    tip_model(s, a, v_prev[:1])[0].sum().backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in tip_model.material.parameters())


def test_tip_model_stroke_vanishes_at_zero_volts(tip_model):
    stroke, fy = tip_model.material_response(torch.tensor([0.0, 200.0], dtype=torch.float64))
    assert stroke[0].item() == 0.0 and stroke[1].item() < 0 and fy[1].item() > 0


def _paper_model(sweep) -> PhysicsModel:
    tr = transitions([sweep["C1"]], 1)
    torch.manual_seed(0)
    model = PhysicsModel(Normalisation.from_transitions(tr), InputRange.from_transitions(tr)).double()
    model.set_setup(1.36e-3, 0.2, 150.0)
    return model


def test_paper_model_gradients_wrt_phi_match_finite_differences(sweep):
    model = _paper_model(sweep)
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


def test_paper_model_is_differentiable_in_state_action_and_weights(sweep):
    model = _paper_model(sweep)
    s = torch.tensor([[-2e-4, -1.2e-3]], dtype=torch.float64, requires_grad=True)
    a = torch.tensor([[180.0, 1e-3]], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda s, a: model(s, a)[0], (s, a), eps=1e-9, atol=1e-7, rtol=1e-4)
    model(s, a)[0].sum().backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in model.material.parameters())


def test_build_rejects_unknown_kind(sweep):
    tr = transitions([sweep["C1"]], 1)
    with pytest.raises(ValueError, match="unknown model kind"):
        build("gp", Normalisation.from_transitions(tr), InputRange.from_transitions(tr))
