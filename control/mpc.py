"""A batched, box-constrained iLQR (Gauss–Newton DDP) in torch float64.

(Longer than ~500 lines on purpose: one algorithm, its costs, linearisation, backward and
forward passes and the envelope-theorem gradients, read and tested together.)

The problem, for each of B rows at once::

    min_u  J = Σ_{t=0}^{T-1} ℓ_t(x_t, u_t) + ℓ_T(x_T)
    s.t.   x_{t+1} = f(x_t, u_t),  x_0 given,  lower_t ≤ u_t ≤ upper_t

with any differentiable dynamics ``f(x (N, n), u (N, m)) -> (N, n)`` whose rows are
independent (a surrogate step, a linear map, ...) and a twice-differentiable cost
(:class:`QuadCost`, or :class:`GeneralCost` differentiated by ``torch.func``). With
``C_final=None`` the last state carries no cost, as in mpc.pytorch.

Each iteration (Tassa, Erez & Todorov 2014, "Control-limited differential dynamic
programming"; the dynamics linearised, as in iLQR and mpc.pytorch):

1. **Linearise** the dynamics along the whole nominal trajectory in one batched autograd
   pass (:func:`linearize`): the B·T rows are stacked n times, the i-th copy gets the unit
   cotangent e_i, and one backward pass returns every A_t = ∂f/∂x and B_t = ∂f/∂u. A
   dynamics object may instead give its own ``jacobian(x, u) -> (A, B)`` (analytic).
2. **Backward pass**: the Riccati recursion with a box-constrained QP per step
   (:func:`box_qp`: projected Newton; closed form for m = 1); on the clamped controls the
   feedback gain is zero. Levenberg–Marquardt regularisation μ on V_xx, per row.
3. **Forward pass with a parallel line search**: the closed-loop rollouts
   u_t = clip(ū_t + α k_t + K_t (x_t − x̄_t), lower_t, upper_t) for every step size α of
   ``alphas`` at once (B·len(alphas) rows); each row keeps its lowest cost if it is lower
   than the nominal one, else μ grows tenfold and the nominal stays.

The number of iterations is fixed (``iterations``) unless ``tol`` > 0 stops earlier. Warm
starts: :func:`shift` turns the previous plan into the next initial guess.

Derivatives of the solution. At the returned plan, ``Solution.K[:, 0]`` is the feedback
gain ∂u*_0/∂x_0 (exact for an LQ problem and for inactive bounds of a converged plan;
Gauss–Newton otherwise) and ``Solution.value_x0`` the gradient of the optimal cost with
respect to x_0 from the backward pass. :func:`value_and_grad` gives dJ*/dθ for any tensor θ
the dynamics or cost use (e.g. φ), by the envelope theorem: at a KKT point with bounds that
do not depend on θ, dJ*/dθ = ∂J(u*; θ)/∂θ with the plan held fixed.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import torch

#: step sizes tried in parallel by the line search
ALPHAS = (1.0, 0.5, 0.25, 0.125, 0.0625, 0.03125, 0.0078125, 0.001)
#: regularisation after the first failure, growth factor, and largest value
MU_MIN, MU_FACTOR, MU_MAX = 1e-6, 10.0, 1e10

Dynamics = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


# --- costs ----------------------------------------------------------------------------------

@dataclass(frozen=True)
class Quadratic:
    """The second-order model of a cost along a trajectory (B rows, T steps).

    lx (B, T, n), lu (B, T, m), lxx (B, T, n, n), luu (B, T, m, m), lux (B, T, m, n);
    vx (B, n), vxx (B, n, n) of the final cost.
    """

    lx: torch.Tensor
    lu: torch.Tensor
    lxx: torch.Tensor
    luu: torch.Tensor
    lux: torch.Tensor
    vx: torch.Tensor
    vxx: torch.Tensor


@dataclass(frozen=True)
class QuadCost:
    """ℓ_t = ½ τᵀ C τ + cᵀ τ with τ = (x_t, u_t); ℓ_T = ½ xᵀ C_final x + c_finalᵀ x.

    Parameters
    ----------
    C : torch.Tensor
        (n+m, n+m), or broadcastable to (B, T, n+m, n+m) for time-varying or per-row costs;
        symmetric.
    c : torch.Tensor
        (n+m,), or broadcastable to (B, T, n+m).
    C_final, c_final : torch.Tensor or None
        (n, n) and (n,) (or with a leading B); None: no cost on x_T.
    """

    C: torch.Tensor
    c: torch.Tensor
    C_final: torch.Tensor | None = None
    c_final: torch.Tensor | None = None

    def stage(self, x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """ℓ_t of every row and step: x (B, T, n), u (B, T, m) -> (B, T)."""
        tau = torch.cat([x, u], -1)
        return 0.5 * (tau.unsqueeze(-2) @ self.C @ tau.unsqueeze(-1))[..., 0, 0] + (tau * self.c).sum(-1)

    def final(self, x: torch.Tensor) -> torch.Tensor:
        """ℓ_T: x (B, n) -> (B,)."""
        value = torch.zeros(x.shape[:-1], dtype=x.dtype, device=x.device)
        if self.C_final is not None:
            value = value + 0.5 * (x.unsqueeze(-2) @ self.C_final @ x.unsqueeze(-1))[..., 0, 0]
        if self.c_final is not None:
            value = value + (x * self.c_final).sum(-1)
        return value

    def quadratize(self, x: torch.Tensor, u: torch.Tensor, x_final: torch.Tensor) -> Quadratic:
        n = x.shape[-1]
        B, T = x.shape[:2]
        tau = torch.cat([x, u], -1)
        C = self.C.expand(B, T, *self.C.shape[-2:])
        g = (C @ tau.unsqueeze(-1))[..., 0] + self.c
        zeros = torch.zeros(B, n, n, dtype=x.dtype, device=x.device)
        vxx = zeros + (self.C_final if self.C_final is not None else 0.0)
        vx = (vxx @ x_final.unsqueeze(-1))[..., 0]
        if self.c_final is not None:
            vx = vx + self.c_final
        return Quadratic(lx=g[..., :n], lu=g[..., n:], lxx=C[..., :n, :n], luu=C[..., n:, n:], lux=C[..., n:, :n],
                         vx=vx, vxx=vxx)


@dataclass(frozen=True)
class GeneralCost:
    """A cost given as functions of one row, differentiated twice by ``torch.func``.

    Parameters
    ----------
    stage_fn : callable
        ``stage_fn(x (n,), u (m,), t (0-d tensor)) -> 0-d tensor``; written with torch
        operations only (it is vmapped).
    final_fn : callable, optional
        ``final_fn(x (n,)) -> 0-d tensor``; None: no cost on x_T.
    """

    stage_fn: Callable
    final_fn: Callable | None = None

    def stage(self, x, u):
        lead, T = x.shape[:-1], x.shape[-2]
        t = torch.arange(T, dtype=x.dtype, device=x.device).expand(lead)
        values = torch.vmap(self.stage_fn)(x.reshape(-1, x.shape[-1]), u.reshape(-1, u.shape[-1]), t.reshape(-1))
        return values.reshape(lead)

    def final(self, x):
        if self.final_fn is None:
            return torch.zeros(x.shape[:-1], dtype=x.dtype, device=x.device)
        return torch.vmap(self.final_fn)(x.reshape(-1, x.shape[-1])).reshape(x.shape[:-1])

    def quadratize(self, x, u, x_final) -> Quadratic:
        B, T, n = x.shape
        m = u.shape[-1]
        t = torch.arange(T, dtype=x.dtype, device=x.device).expand(B, T).reshape(-1)

        def joint(tau, time):
            return self.stage_fn(tau[:n], tau[n:], time)
        tau = torch.cat([x, u], -1).reshape(B * T, n + m)
        g = torch.vmap(torch.func.grad(joint))(tau, t).reshape(B, T, n + m)
        H = torch.vmap(torch.func.jacrev(torch.func.jacrev(joint)))(tau, t).reshape(B, T, n + m, n + m)
        if self.final_fn is None:
            vx = torch.zeros(B, n, dtype=x.dtype, device=x.device)
            vxx = torch.zeros(B, n, n, dtype=x.dtype, device=x.device)
        else:
            vx = torch.vmap(torch.func.grad(self.final_fn))(x_final)
            vxx = torch.vmap(torch.func.jacrev(torch.func.jacrev(self.final_fn)))(x_final)
        return Quadratic(lx=g[..., :n], lu=g[..., n:], lxx=H[..., :n, :n], luu=H[..., n:, n:], lux=H[..., n:, :n],
                         vx=vx, vxx=vxx)


def total_cost(cost, x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """J of trajectories x (..., T+1, n) under u (..., T, m) -> (...)."""
    return cost.stage(x[..., :-1, :], u).sum(-1) + cost.final(x[..., -1, :])


# --- dynamics: rollouts and the batched linearisation ---------------------------------------

def rollout(dynamics: Dynamics, x0: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """Open-loop states x (B, T+1, n) from x0 (B, n) under u (B, T, m)."""
    xs = [x0]
    for t in range(u.shape[1]):
        xs.append(dynamics(xs[-1], u[:, t]))
    return torch.stack(xs, 1)


def linearize(dynamics: Dynamics, x: torch.Tensor, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """A = ∂f/∂x (B, ..., n, n) and B = ∂f/∂u (B, ..., n, m) at every row of x (B, ..., n), u (B, ..., m).

    One forward and one backward pass over n stacked copies of all the rows: copy i gets
    the cotangent e_i, so the gradient of copy i is row i of each row's Jacobian. The rows
    of ``dynamics`` must be independent (a batch of separate states), which lets it hold
    any control flow (no vmap needed); they are ordered so that row r belongs to batch row
    r mod B. ``dynamics.jacobian(x, u)`` (rows in the same order), where defined, is used
    instead.
    """
    n, m = x.shape[-1], u.shape[-1]
    moved = x.movedim(0, -2).shape[:-1]          # (..., B): batch row fastest
    xf = x.detach().movedim(0, -2).reshape(-1, n)
    uf = u.detach().movedim(0, -2).reshape(-1, m)

    def back(J, cols):
        return J.reshape(*moved, n, cols).movedim(-3, 0)
    jac = getattr(dynamics, "jacobian", None)
    if callable(jac):
        A, Bu = jac(xf, uf)
        return back(A, n), back(Bu, m)
    N = xf.shape[0]
    with torch.enable_grad():
        xr = xf.repeat(n, 1).requires_grad_(True)
        ur = uf.repeat(n, 1).requires_grad_(True)
        y = dynamics(xr, ur)
        seed = torch.eye(n, dtype=y.dtype, device=y.device).repeat_interleave(N, 0)
        gx, gu = torch.autograd.grad(y, (xr, ur), seed, allow_unused=True)
    gx = torch.zeros_like(xr) if gx is None else gx
    gu = torch.zeros_like(ur) if gu is None else gu
    return back(gx.reshape(n, N, n).transpose(0, 1), n), back(gu.reshape(n, N, m).transpose(0, 1), m)


# --- the box-constrained QP of each step ----------------------------------------------------

def box_qp(H: torch.Tensor, g: torch.Tensor, lower: torch.Tensor, upper: torch.Tensor, x0: torch.Tensor | None = None,
           iterations: int = 20) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """min ½ δᵀ H δ + gᵀ δ s.t. lower ≤ δ ≤ upper, batched over the leading dimensions.

    Projected Newton (Bertsekas 1982, as in Tassa et al. 2014): Newton steps on the free
    set with an Armijo search along the projection arc; m = 1 in closed form.

    Returns
    -------
    (δ, free, ok)
        The solution (..., m), the controls not held at a bound (bool (..., m)), and whether
        H was positive definite on the free set (bool (...)).
    """
    m = g.shape[-1]
    if m == 1:
        h, q = H[..., 0, 0], g[..., 0]
        ok = h > 0
        d = torch.where(ok, -q / torch.where(ok, h, torch.ones_like(h)), torch.zeros_like(q))
        x = torch.minimum(torch.maximum(d, lower[..., 0]), upper[..., 0])
        free = (d > lower[..., 0]) & (d < upper[..., 0])
        return x.unsqueeze(-1), free.unsqueeze(-1), ok
    x = torch.zeros_like(g) if x0 is None else x0
    x = torch.minimum(torch.maximum(x, lower), upper)
    eye = torch.eye(m, dtype=H.dtype, device=H.device).expand_as(H)
    ok = torch.ones(g.shape[:-1], dtype=torch.bool, device=g.device)
    steps = (0.5 ** torch.arange(12, dtype=H.dtype, device=H.device)).unsqueeze(-1)

    def clamped_set(v):
        grad = (H @ v.unsqueeze(-1))[..., 0] + g
        return grad, ((v <= lower) & (grad > 0)) | ((v >= upper) & (grad < 0))

    for _ in range(iterations):
        grad, clamped = clamped_set(x)
        free = ~clamped
        L, info = torch.linalg.cholesky_ex(torch.where(free.unsqueeze(-1) & free.unsqueeze(-2), H, eye))
        ok = ok & (info == 0)
        d = -torch.cholesky_solve(torch.where(free, grad, 0.0).unsqueeze(-1), L)[..., 0]
        # the projection arc x(s) = clip(x + s d) at s = 1, 1/2, ..., Armijo on each
        trial = torch.minimum(torch.maximum(x.unsqueeze(-2) + steps * d.unsqueeze(-2), lower.unsqueeze(-2)),
                              upper.unsqueeze(-2))
        change = trial - x.unsqueeze(-2)
        decrease = -(0.5 * ((change @ H) * change).sum(-1) + (change * grad.unsqueeze(-2)).sum(-1))
        expected = -(change * grad.unsqueeze(-2)).sum(-1)
        good = (decrease >= 0.1 * expected) & (expected > 0)
        first = good.to(torch.int8).argmax(-1)
        pick = torch.gather(trial, -2, first[..., None, None].expand(*first.shape, 1, m))[..., 0, :]
        moved = good.any(-1).unsqueeze(-1) & (pick != x)
        if not bool(moved.any()):
            break
        x = torch.where(moved, pick, x)
    _, clamped = clamped_set(x)
    return x, ~clamped, ok


# --- one iteration: backward and forward pass -----------------------------------------------

@dataclass
class Gains:
    """The backward pass's result: feed-forward k (B, T, m), feedback K (B, T, m, n), the
    controls not held at a bound (free, bool (B, T, m)), the expected decrease terms
    dV = (Σ kᵀQ_u, Σ ½ kᵀQ_uu k) (B, 2), whether every step's Q_uu was positive definite on
    its free set (ok (B,)), and the gradient of the cost-to-go at x_0 (vx0 (B, n))."""

    k: torch.Tensor
    K: torch.Tensor
    free: torch.Tensor
    dV: torch.Tensor
    ok: torch.Tensor
    vx0: torch.Tensor


def backward_pass(A: torch.Tensor, Bu: torch.Tensor, q: Quadratic, du_lower: torch.Tensor, du_upper: torch.Tensor,
                  mu: torch.Tensor) -> Gains:
    """The Riccati recursion of box-DDP along a linearised trajectory.

    Parameters
    ----------
    A, Bu : torch.Tensor
        (B, T, n, n) and (B, T, n, m): the dynamics' Jacobians.
    q : Quadratic
        The cost's second-order model.
    du_lower, du_upper : torch.Tensor
        (B, T, m): bounds on the control change (lower − ū, upper − ū).
    mu : torch.Tensor
        (B,): regularisation added to V_xx where the gains are computed (Tassa's state
        regularisation; μ = 0 gives the exact LQR step).
    """
    Bn, T, n, m = Bu.shape
    Vx, Vxx = q.vx, q.vxx
    mu_ = mu[:, None, None]
    ks, Ks, frees = [None] * T, [None] * T, [None] * T
    dV1 = torch.zeros(Bn, dtype=A.dtype, device=A.device)
    dV2 = torch.zeros_like(dV1)
    ok = torch.ones(Bn, dtype=torch.bool, device=A.device)
    eye_m = torch.eye(m, dtype=A.dtype, device=A.device)
    for t in reversed(range(T)):
        At, Bt = A[:, t], Bu[:, t]
        AtT, BtT = At.transpose(-1, -2), Bu[:, t].transpose(-1, -2)
        Qx = q.lx[:, t] + (AtT @ Vx.unsqueeze(-1))[..., 0]
        Qu = q.lu[:, t] + (BtT @ Vx.unsqueeze(-1))[..., 0]
        BV = BtT @ Vxx
        Qxx = q.lxx[:, t] + AtT @ Vxx @ At
        Quu = q.luu[:, t] + BV @ Bt
        Qux = q.lux[:, t] + BV @ At
        Quu_r = Quu + mu_ * (BtT @ Bt)
        Qux_r = Qux + mu_ * (BtT @ At)
        k, free, ok_t = box_qp(Quu_r, Qu, du_lower[:, t], du_upper[:, t])
        ok = ok & ok_t
        if m == 1:
            h = Quu_r[..., 0, 0]
            K = torch.where(free.unsqueeze(-1) & ok_t[:, None, None], -Qux_r / torch.where(ok_t, h, 1.0)[:, None, None],
                            0.0)
        else:
            both = free.unsqueeze(-1) & free.unsqueeze(-2)
            L, _ = torch.linalg.cholesky_ex(torch.where(both, Quu_r, eye_m))
            K = torch.where(free.unsqueeze(-1), -torch.cholesky_solve(torch.where(free.unsqueeze(-1), Qux_r, 0.0), L),
                            0.0)
        KT = K.transpose(-1, -2)
        Quu_k = (Quu @ k.unsqueeze(-1))[..., 0]
        Vx = Qx + (KT @ (Quu_k + Qu).unsqueeze(-1))[..., 0] + (Qux.transpose(-1, -2) @ k.unsqueeze(-1))[..., 0]
        Vxx = Qxx + KT @ Quu @ K + KT @ Qux + Qux.transpose(-1, -2) @ K
        Vxx = 0.5 * (Vxx + Vxx.transpose(-1, -2))
        dV1 = dV1 + (k * Qu).sum(-1)
        dV2 = dV2 + 0.5 * (k * Quu_k).sum(-1)
        ks[t], Ks[t], frees[t] = k, K, free
    return Gains(k=torch.stack(ks, 1), K=torch.stack(Ks, 1), free=torch.stack(frees, 1),
                 dV=torch.stack([dV1, dV2], -1), ok=ok, vx0=Vx)


def forward_pass(dynamics: Dynamics, x0: torch.Tensor, x_bar: torch.Tensor, u_bar: torch.Tensor, gains: Gains,
                 lower: torch.Tensor, upper: torch.Tensor, alphas: torch.Tensor):
    """Closed-loop rollouts for every step size at once.

    Row a·B + b of the dynamics' input is batch row b under step size ``alphas[a]``.

    Returns
    -------
    (x, u)
        (S, B, T+1, n) and (S, B, T, m) for the S step sizes.
    """
    S, (Bn, T, m), n = alphas.shape[0], u_bar.shape, x0.shape[-1]
    x = x0.repeat(S, 1)
    xb, ub = x_bar.repeat(S, 1, 1), u_bar.repeat(S, 1, 1)
    kk = (alphas.repeat_interleave(Bn)[:, None, None] * gains.k.repeat(S, 1, 1))
    KK = gains.K.repeat(S, 1, 1, 1)
    lo, hi = lower.repeat(S, 1, 1), upper.repeat(S, 1, 1)
    xs, us = [x], []
    for t in range(T):
        u = ub[:, t] + kk[:, t] + (KK[:, t] @ (x - xb[:, t]).unsqueeze(-1))[..., 0]
        u = torch.minimum(torch.maximum(u, lo[:, t]), hi[:, t])
        x = dynamics(x, u)
        xs.append(x)
        us.append(u)
    return torch.stack(xs, 1).reshape(S, Bn, T + 1, n), torch.stack(us, 1).reshape(S, Bn, T, m)


# --- the solver -----------------------------------------------------------------------------

@dataclass
class Solution:
    """What :func:`solve` returns.

    Attributes
    ----------
    x : torch.Tensor
        (B, T+1, n) states of the plan, x[:, 0] = x_0.
    u : torch.Tensor
        (B, T, m) controls of the plan.
    cost : torch.Tensor
        (B,) its cost J.
    history : torch.Tensor
        (B, iterations + 1): J after each iteration (the first: the initial guess).
    mu : torch.Tensor
        (B,) final regularisation.
    iterations : int
        Iterations run.
    gains : Gains or None
        The backward pass at the returned plan (``gains=True``): K[:, 0] = ∂u*_0/∂x_0 on the
        free controls, vx0 = ∂J*/∂x_0.
    """

    x: torch.Tensor
    u: torch.Tensor
    cost: torch.Tensor
    history: torch.Tensor
    mu: torch.Tensor
    iterations: int
    gains: Gains | None = field(default=None, repr=False)


def _bounds(bound, like: torch.Tensor, sign: float) -> torch.Tensor:
    if bound is None:
        return torch.full_like(like, sign * math.inf)
    return torch.as_tensor(bound, dtype=like.dtype, device=like.device).expand_as(like).contiguous()


def solve(dynamics: Dynamics, cost, x0: torch.Tensor, u_init: torch.Tensor, lower=None, upper=None, *,
          iterations: int = 20, alphas=ALPHAS, tol: float = 0.0, mu0: float = 0.0, gains: bool = False) -> Solution:
    """Solve the box-constrained optimal control problem by iLQR, batched over rows.

    Parameters
    ----------
    dynamics : callable
        ``dynamics(x (N, n), u (N, m)) -> (N, n)``, rows independent; N is a multiple of B
        and row r belongs to batch row r mod B (per-row parameters: ``.repeat`` them).
        Optional ``dynamics.jacobian(x, u) -> (A, B)`` replaces autograd.
    cost : QuadCost or GeneralCost
    x0 : torch.Tensor
        (B, n) initial states.
    u_init : torch.Tensor
        (B, T, m) initial guess (clipped to the bounds): zeros, a ramp, or the previous
        plan shifted by :func:`shift`.
    lower, upper : tensor-like or None
        Bounds on u, broadcastable to (B, T, m); None: unbounded.
    iterations : int
        Most iterations (all are run when ``tol`` = 0).
    alphas : sequence of float
        Line-search step sizes, tried in parallel.
    tol : float
        Stop once no row's cost fell by more than ``tol``·(1 + |J|) in an iteration.
    mu0 : float
        Initial regularisation (0: exact Newton/LQR steps until a step fails).
    gains : bool
        Also run the backward pass at the returned plan (:attr:`Solution.gains`).

    Returns
    -------
    Solution
    """
    x0 = torch.as_tensor(x0, dtype=torch.float64)
    u = torch.as_tensor(u_init, dtype=torch.float64, device=x0.device)
    lo, hi = _bounds(lower, u, -1.0), _bounds(upper, u, 1.0)
    u = torch.minimum(torch.maximum(u, lo), hi)
    steps = torch.as_tensor(alphas, dtype=u.dtype, device=u.device)
    with torch.no_grad():
        x = rollout(dynamics, x0, u)
        J = _finite(total_cost(cost, x, u))
        mu = torch.full_like(J, float(mu0))
        history = [J]
        done = 0
        for done in range(1, iterations + 1):
            A, Bu = linearize(dynamics, x[:, :-1], u)
            g = backward_pass(A, Bu, cost.quadratize(x[:, :-1], u, x[:, -1]), lo - u, hi - u, mu)
            xs, us = forward_pass(dynamics, x0, x, u, g, lo, hi, steps)
            Js = _finite(total_cost(cost, xs, us))
            best = Js.argmin(0)
            rows = torch.arange(J.shape[0], device=J.device)
            J_new = Js[best, rows]
            better = g.ok & (J_new < J)
            x = torch.where(better[:, None, None], xs[best, rows], x)
            u = torch.where(better[:, None, None], us[best, rows], u)
            gain = J - J_new
            J = torch.where(better, J_new, J)
            mu = torch.where(better, torch.where(mu / MU_FACTOR < MU_MIN, 0.0, mu / MU_FACTOR),
                             torch.clamp(torch.clamp(mu * MU_FACTOR, min=MU_MIN), max=MU_MAX))
            history.append(J)
            if tol > 0 and bool(torch.all(~better | (gain <= tol * (1 + J.abs())))):
                break
        final = None
        if gains:
            A, Bu = linearize(dynamics, x[:, :-1], u)
            final = backward_pass(A, Bu, cost.quadratize(x[:, :-1], u, x[:, -1]), lo - u, hi - u,
                                  torch.zeros_like(mu))
    return Solution(x=x, u=u, cost=J, history=torch.stack(history, 1), mu=mu, iterations=done, gains=final)


def _finite(J: torch.Tensor) -> torch.Tensor:
    return torch.where(torch.isfinite(J), J, torch.full_like(J, math.inf))


def shift(u: torch.Tensor, fill: torch.Tensor | None = None) -> torch.Tensor:
    """The warm start of the next MPC step: the plan u (B, T, m) one step on, its last
    control repeated (or ``fill`` (B, m))."""
    last = u[:, -1:] if fill is None else torch.as_tensor(fill, dtype=u.dtype).reshape(u.shape[0], 1, -1)
    return torch.cat([u[:, 1:], last], 1)


def value_and_grad(dynamics: Dynamics, cost, x0: torch.Tensor, u: torch.Tensor, wrt=()) -> tuple:
    """J(u; x_0, θ) of the fixed plan ``u`` and its gradients with respect to x_0 and the
    tensors ``wrt`` (parameters the dynamics or cost read).

    At an optimal plan whose bounds do not depend on them, these are the gradients of the
    optimal cost J* (envelope theorem).

    Returns
    -------
    (J, dJ_dx0, [dJ_dθ ...])
    """
    with torch.enable_grad():
        x0 = torch.as_tensor(x0, dtype=torch.float64).detach().requires_grad_(True)
        J = total_cost(cost, rollout(dynamics, x0, u.detach()), u.detach())
        grads = torch.autograd.grad(J.sum(), (x0, *wrt), allow_unused=True)
    return J.detach(), grads[0], list(grads[1:])
