"""The tip-memory model (kind f-memory): its step solves its equations, reduces to the
tip-contact model for a rigid tip, reverses the friction with the hysteresis of a compliant
tip when the stroke turns, has exact gradients, and its batch-1 float path equals the torch one."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from deapull.surrogate.models import tip_coin_step, tip_memory_step
from deapull.surrogate.models.memory import tip_memory_step_scalar

G, EPS, MASS, MU_T, MU_B = 9.8, 1e-4, 1.36e-3, 0.5, 0.2


def _rows(n=400, seed=0):
    """Random steps: a coin at rest or sliding either way, strokes jumping either way."""
    gen = torch.Generator().manual_seed(seed)

    def uni(lo, hi):
        return lo + (hi - lo) * torch.rand(n, generator=gen, dtype=torch.float64)
    u = uni(-0.01, 0.01) * (torch.rand(n, generator=gen, dtype=torch.float64) > 0.3)
    P = uni(-1e-3, 1e-3)
    X = P + uni(-3e-5, 3e-5)
    return dict(u=u, P=P, X_next=X, c=uni(1e-3, 1e-2), fy0=uni(2e-3, 5e-2), b=uni(-0.3, 0.3),
                dt=uni(1e-4, 2e-3), T_start=uni(-0.01, 0.01))


def _step(r, **kw):
    return tip_memory_step(r["u"], r["P"], r["X_next"], r["c"], r["fy0"], r["b"], MU_T, MU_B, MASS, r["dt"], G, EPS,
                           T_start=r.get("T_start"), **kw)


def test_every_step_satisfies_its_equations():
    """Tip spring, regularised tip friction with Fy = Fy0 + b T, backward-Euler coin with the
    ground force in the Coulomb cone: all at round-off, for 400 random steps."""
    r = _rows()
    with torch.no_grad():
        u1, T, fy, P1 = _step(r)
    assert torch.allclose(fy, r["fy0"] + r["b"] * T, rtol=0, atol=1e-15)
    assert torch.allclose(P1, r["X_next"] - r["c"] * T, rtol=0, atol=1e-15)
    s = (P1 - r["P"]) / r["dt"] - u1
    friction = MU_T * torch.clamp(fy, min=0) * s / torch.sqrt(s * s + EPS * EPS)
    assert float((T - friction).abs().max()) < 1e-11 * float(T.abs().max())      # round-off
    ground = T - MASS * (u1 - r["u"]) / r["dt"]                 # B from the coin's momentum balance
    cap = MU_B * torch.clamp(MASS * G + fy, min=0)
    assert bool(torch.all(ground.abs() <= cap * (1 + 1e-9) + 1e-15))
    moving = u1 != 0
    assert bool(torch.all((ground[moving] - cap[moving] * torch.sign(u1[moving])).abs() < 1e-12))
    assert 50 < int(moving.sum()) < 400                        # both stick and slip are tested


def test_batch_one_float_path_equals_the_torch_solve():
    r = _rows(60, seed=1)
    with torch.no_grad():
        u1, T, fy, P1 = _step(r)
    for i in range(60):
        out = tip_memory_step_scalar(*(float(r[k][i]) for k in ("u", "P", "X_next", "c", "fy0", "b")), MU_T, MU_B, MASS,
                                     float(r["dt"][i]), G, EPS, T_start=float(r["T_start"][i]))
        assert out == pytest.approx((float(u1[i]), float(T[i]), float(fy[i]), float(P1[i])), rel=1e-10, abs=1e-14)


def test_a_rigid_tip_is_the_tip_contact_model():
    """c → 0 and b = 0: the tip moves with its stroke, w = (X' − P)/Δt, as in f-coulomb."""
    r = _rows(200, seed=2)
    r["c"] = torch.full_like(r["c"], 1e-13)
    r["b"] = torch.zeros_like(r["b"])
    with torch.no_grad():
        u1, T, fy, _ = _step(r)
        w = (r["X_next"] - r["P"]) / r["dt"]
        u_ref, T_ref = tip_coin_step(r["u"], w, MU_T * r["fy0"], MU_B * (MASS * G + r["fy0"]), MASS, r["dt"], EPS)
    assert float((u1 - u_ref).abs().max()) < 1e-8 * float(w.abs().max())
    assert float((T - T_ref).abs().max()) < 1e-9


def _drive(c, steps_out=60, steps_back=60, speed=5e-3, dt=1e-3, fy=0.02):
    """Stroke toward −x at ``speed``, then back toward +x: the coin's u, x and the friction T."""
    one = lambda v: torch.tensor([v], dtype=torch.float64)    # noqa: E731
    u, x, P, X, T = one(0.0), 0.0, one(0.0), 0.0, one(0.0)
    out = []
    for k in range(steps_out + steps_back):
        X += (-speed if k < steps_out else speed) * dt
        with torch.no_grad():
            u, T, _, P = tip_memory_step(u, P, one(X), one(c), one(fy), one(0.0), MU_T, MU_B, MASS, one(dt), G, EPS,
                                         T_start=T)
        x += dt * float(u)
        out.append((float(u), x, float(T), X))
    return np.array(out)


def test_when_the_stroke_turns_the_friction_reverses_with_the_tips_hysteresis():
    """A compliant tip (c = 5 mm/N) drags the coin toward −x, then the stroke turns: the coin
    stops, the tip sticks to it while its force swings from −μ_b N to +μ_b N (a dead band of
    2 μ_b N c = 67 µm of stroke, 13 steps here), then it drags the coin back toward +x at the
    tip's speed. A rigid tip (c → 0) turns the coin at once."""
    c, speed, dt, fy = 5e-3, 5e-3, 1e-3, 0.02
    normal = MASS * G + fy
    run = _drive(c, steps_out=100, speed=speed, dt=dt, fy=fy)
    out, back = run[:100], run[100:]
    assert out[-1, 0] == pytest.approx(-speed, rel=0.05)              # carried at the tip's speed (a small lag)
    assert out[-1, 2] == pytest.approx(-MU_B * normal, rel=0.02)      # pushing against the ground
    still = np.flatnonzero(back[:, 0] == 0.0)
    assert still[0] <= 3                                               # stops within a few steps
    restart = int(np.flatnonzero(back[:, 0] > 0)[0])
    stroke_back = restart * speed * dt
    assert 0.7 * 2 * MU_B * normal * c < stroke_back < 1.3 * 2 * MU_B * normal * c
    assert back[still[0], 2] < 0 < back[restart - 1, 2]               # T changed sign while the coin stood
    assert back[-1, 0] == pytest.approx(speed, rel=0.05) and back[-1, 1] > back[restart - 1, 1]   # toward +x
    rigid = _drive(1e-12, steps_out=100, speed=speed, dt=dt, fy=fy)[100:]
    assert int(np.flatnonzero(rigid[:, 0] > 0)[0]) <= 2


def test_gradients_of_the_step_are_those_of_the_exact_root():
    """Implicit differentiation through the solve: gradcheck in every input of sliding rows."""
    r = _rows(40, seed=3)
    with torch.no_grad():
        u1, _, _, _ = _step(r)
    keep = u1.abs() > 1e-4                                              # away from the stick kink
    names = ("u", "P", "X_next", "c", "fy0", "b", "dt")
    args = tuple(r[k][keep][:6].clone().requires_grad_(True) for k in names)

    def f(*a):
        out = tip_memory_step(*a[:6], MU_T, MU_B, MASS, a[6], G, EPS)
        return torch.stack([out[0], out[1], out[2]])
    assert torch.autograd.gradcheck(f, args, eps=1e-10, atol=1e-6, rtol=1e-4)
    assert math.isfinite(float(f(*args).detach().sum()))
