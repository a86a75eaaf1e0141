"""Checks of a compiled coin model against the torch path, shared by the f-coulomb and f-memory
solvers' tests: its Jacobians against central differences, its box-iLQR plans against
:func:`mpc.solve`'s."""
from __future__ import annotations

import torch

from deapull.control import mpc

F64 = torch.float64


def assert_plans_match_torch(slow, fast, cost, x0, iterations: int, T: int = 10, improving: int = 3):
    """The compiled box-iLQR of ``fast`` against :func:`mpc.solve` on ``slow`` (the torch
    dynamics of the same model) from the rows ``x0`` (3 of them: two start from a full push, one
    from none): the first ``improving`` plans improve, the cost histories agree to 1e-10, the
    plans and states to 1e-6. Returns (the start plan u0, torch solution, compiled solution)."""
    u0 = torch.cat([torch.ones(2, T, 1, dtype=F64), torch.zeros(1, T, 1, dtype=F64)])
    ref = mpc.solve(slow, cost, x0, u0, -1.0, 1.0, iterations=iterations)
    got = fast.solve(cost, x0, u0, -1.0, 1.0, iterations=iterations)
    assert bool((ref.history[:improving, -1] < ref.history[:improving, 0]).all())     # the plans improved
    torch.testing.assert_close(got.history, ref.history, rtol=1e-10, atol=1e-10)
    torch.testing.assert_close(got.u, ref.u, rtol=0, atol=1e-6)
    torch.testing.assert_close(got.x, ref.x, rtol=0, atol=1e-6)
    return u0, ref, got


def assert_jacobians_match_central_differences(fast, xi, nu, A, B, dv_scale: float, h: float = 1e-7) -> None:
    """[A B] against central differences of ``fast`` on the rows whose stick/slip state and
    voltage clipping hold over ±h (errors there are O(h), elsewhere round-off): more than 100
    such rows, 95 % of them within 1e-4 relative beyond the difference's own round-off (a few ulps
    of the outputs over 2h, which an entry that is 0 in [A B] shows as ~1e-9). ``dv_scale``: V's
    change per unit ν in ξ's V unit."""
    n = xi.shape[1]
    fd = torch.empty(len(xi), n, n + 1, dtype=F64)
    noise = torch.zeros(len(xi), n, n + 1, dtype=F64)
    same = torch.ones(len(xi), dtype=torch.bool)
    base = fast(xi, nu)
    eps = torch.finfo(F64).eps
    for j in range(n + 1):
        e = torch.zeros(len(xi), n + 1, dtype=F64)
        e[:, j] = h
        plus, minus = fast(xi + e[:, :n], nu + e[:, n:]), fast(xi - e[:, :n], nu - e[:, n:])
        fd[:, :, j] = (plus - minus) / (2 * h)
        # the difference's round-off: a few ulps of the outputs over the step 2h
        noise[:, :, j] = 4 * eps * (plus.abs() + minus.abs()) / (2 * h)
        same &= ((plus[:, 1] == 0) == (base[:, 1] == 0)) & ((minus[:, 1] == 0) == (base[:, 1] == 0))
    V_next = xi[:, 2] + dv_scale * nu[:, 0]
    same &= (V_next > 1e-6) & (V_next < 4 - 1e-6)
    jac = torch.cat([A, B], -1)
    err = ((fd - jac).abs() - noise).clamp(min=0.0) / (1e-6 + jac.abs())
    close = (err < 1e-4).all(-1).all(-1)
    assert int(same.sum()) > 100 and float(close[same].double().mean()) > 0.95, float(err[same].max())
