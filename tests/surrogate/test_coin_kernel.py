"""The coin's step is defined once in C (surrogate/coin_step.h, included by both native
libraries) and once in torch (tip_coin_step): the two agree on the same inputs to round-off,
in the regimes that matter — stuck, dragged either way, coasting, the tip at rest, the
pressing force gone."""
from __future__ import annotations

import ctypes

import numpy as np
import pytest
import torch

from deapull.surrogate import native
from deapull.surrogate.models.tip_contact import tip_coin_step

EPS, ITERATIONS = 1e-5, 40


def _inputs(n=400, seed=3):
    g = np.random.default_rng(seed)
    mass, dt = 1.36e-3, g.choice([1e-4, 1e-3, 1.4e-3], n)
    u = g.normal(0, 2e-3, n) * (g.random(n) > 0.2)                  # a fifth at rest
    w = g.normal(0, 5e-3, n) * (g.random(n) > 0.1)                  # a tenth with the tip at rest
    cap_t = np.abs(g.normal(0, 0.02, n)) * (g.random(n) > 0.05)     # some without pressing force
    cap_b = 0.2 * (mass * 9.8 + cap_t / 0.5) * g.uniform(0.2, 1.5, n)
    return u, w, cap_t, cap_b, np.full(n, mass), dt


def _c_steps(u, w, cap_t, cap_b, c):
    lib = native.library()
    out, force = np.empty_like(u), np.empty_like(u)
    p = lambda a: np.ascontiguousarray(a, dtype=np.float64).ctypes.data_as(ctypes.POINTER(ctypes.c_double))
    lib.deapull_coin_steps.restype = ctypes.c_int
    lib.deapull_coin_steps(ctypes.c_int(len(u)), p(u), p(w), p(cap_t), p(cap_b), p(c), ctypes.c_double(EPS),
                           ctypes.c_int(ITERATIONS), p(out), p(force))
    return out, force


@pytest.mark.skipif(native.library() is None, reason="no C compiler: the native kernels are not built")
def test_the_c_coin_step_is_the_torch_step_to_round_off():
    u, w, cap_t, cap_b, mass, dt = _inputs()
    T = lambda a: torch.tensor(a, dtype=torch.float64)
    with torch.no_grad():
        u_t, f_t = tip_coin_step(T(u), T(w), T(cap_t), T(cap_b), T(mass), T(dt), EPS, ITERATIONS)
    u_c, f_c = _c_steps(u, w, cap_t, cap_b, mass / dt)
    stuck = u_t.numpy() == 0
    assert 20 < stuck.sum() < len(u) - 20 and (u_t.numpy() > 0).sum() > 20 and (u_t.numpy() < 0).sum() > 20
    np.testing.assert_array_equal(u_c == 0, stuck)                          # the same rows stick
    np.testing.assert_allclose(u_c, u_t.numpy(), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(f_c, f_t.numpy(), rtol=1e-10, atol=1e-15)
