"""Kind ``f-coulomb``: f = d∘m grounded in the FEM's contact mechanics (the tip-contact model).

m (MLP 1 → 3×128 ReLU → 2) maps the voltage to the DEA tip's stroke X(V) and pressing
force Fy(V); d moves the coin between two Coulomb contacts — the tip dragging it with the
FEM's rate-regularised friction μ_t, the ground holding it with exact stick/slip μ_b —
with φ = (m_c, μ_b, μ_t). No V^T is needed.
"""
from __future__ import annotations

import logging

import numpy as np
import torch

from deapull.errors import InputError
from deapull.surrogate.data import Transitions, require_tip_contact
from deapull.surrogate.models.base import (InputRange, NativeKernel, Normalisation, Surrogate, mlp, mlp_params,
                                           state_loss)
from deapull.surrogate.models.registry import register
from deapull.surrogate.phi import Phi

log = logging.getLogger(__name__)


def regularised_slip(v: torch.Tensor, eps: torch.Tensor) -> torch.Tensor:
    """The FEM's rate-regularised Coulomb factor s/√(s² + ε²) ∈ (-1, 1) of a slip rate s
    (ε a float, or a tensor of one per row)."""
    return v / torch.sqrt(v * v + eps * eps)


def tip_coin_step(u, w, cap_t, cap_b, mass_kg, dt, eps, iterations: int = 40):
    """d of the tip-contact model: one backward-Euler step of the coin between two contacts.

    The coin (mass m_c, velocity u) is dragged by the DEA tip moving at w with the FEM's
    rate-regularised friction T = μ_t Fy (w - u')/√((w - u')² + ε²) and held by the ground
    with exact Coulomb stick/slip, |B| ≤ μ_b N:

        m_c (u' - u) / Δt = T(u') - B,   B ∈ μ_b N Sgn(u').

    The right side decreases in u', so the step has one solution: the coin sticks (u' = 0)
    when the tip's pull at u' = 0 plus the coin's momentum stays inside the ground's cone;
    otherwise the sign of u' is known and a bracketed Newton solve finds it. The solve runs
    without gradients, then one Newton correction with them gives the gradients of the
    exact root (implicit differentiation) with respect to every input. The arithmetic is
    :func:`coin_step`, which TorchScript compiles (:mod:`deapull.surrogate.export`).

    Parameters
    ----------
    u, w : torch.Tensor
        Coin velocity before the step and tip velocity over it (m/s).
    cap_t, cap_b : torch.Tensor
        μ_t Fy and μ_b N (N), non-negative.
    mass_kg, dt : torch.Tensor or float
    eps : float or torch.Tensor
        Slip-rate regularisation ε (m/s), > 0; a tensor gives one per row (f-patch's spread),
        and the gradients then reach it too.
    iterations : int
        Most Newton/bisection iterations (they stop once no row changes; a handful suffice).

    Returns
    -------
    (u_next, T) : tuple of torch.Tensor
        The coin velocity after the step and the tip's force on the coin along x (N).
    """
    like = torch.as_tensor(u)
    as_tensor = (lambda v: v if isinstance(v, torch.Tensor) else torch.tensor(v, dtype=like.dtype))
    return coin_step(like, as_tensor(w), as_tensor(cap_t), as_tensor(cap_b), as_tensor(mass_kg), as_tensor(dt),
                     as_tensor(eps), int(iterations))


def _coin_residual(v: torch.Tensor, u: torch.Tensor, w: torch.Tensor, c: torch.Tensor, cap_t: torch.Tensor,
                   sign_cap_b: torch.Tensor, eps: torch.Tensor) -> torch.Tensor:
    return c * (v - u) - cap_t * regularised_slip(w - v, eps) + sign_cap_b


def _coin_slope(v: torch.Tensor, w: torch.Tensor, c: torch.Tensor, cap_t: torch.Tensor,
                eps: torch.Tensor) -> torch.Tensor:
    return c + cap_t * eps * eps / ((w - v) ** 2 + eps * eps) ** 1.5


def coin_step(u: torch.Tensor, w: torch.Tensor, cap_t: torch.Tensor, cap_b: torch.Tensor, mass_kg: torch.Tensor,
              dt: torch.Tensor, eps: torch.Tensor, iterations: int) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`tip_coin_step` on tensors (TorchScript compiles it)."""
    c = mass_kg / dt
    tip_at_rest_coin = cap_t * regularised_slip(w, eps)
    ground_reaction = tip_at_rest_coin + c * u
    stuck = ground_reaction.abs() <= cap_b
    sign = torch.where(ground_reaction > 0, torch.ones_like(u), -torch.ones_like(u))
    sign_cap_b = sign * cap_b
    with torch.no_grad():
        reach = (cap_t + cap_b) / c
        zero = torch.zeros_like(ground_reaction)
        # a stuck row gets the empty bracket [0, 0]: it needs no solve
        lo = torch.where((sign > 0) | stuck, zero, torch.minimum(u - reach, zero))
        hi = torch.where((sign < 0) | stuck, zero, torch.maximum(u + reach, zero))
        # start where the tip's friction balances the ground's alone (inertia neglected)
        ratio = torch.clamp(sign * cap_b / torch.clamp(cap_t, min=1e-300), -0.999999, 0.999999)
        v = torch.minimum(torch.maximum(w - eps * ratio / torch.sqrt(1 - ratio * ratio), lo), hi)
        change = hi - lo
        for _ in range(iterations):
            r = _coin_residual(v, u, w, c, cap_t, sign_cap_b, eps)
            lo, hi = torch.where(r < 0, v, lo), torch.where(r >= 0, v, hi)
            step = r / _coin_slope(v, w, c, cap_t, eps)
            # bisect where Newton leaves the bracket or does not halve its last change
            bisect = (v - step < lo) | (v - step > hi) | (2 * step.abs() > change.abs())
            previous = v
            v = torch.where(bisect, 0.5 * (lo + hi), v - step)
            change = v - previous
            if bool(torch.all(change.abs() <= 1e-13 * (v.abs() + eps))):
                break
    v = v - _coin_residual(v, u, w, c, cap_t, sign_cap_b, eps) / _coin_slope(v, w, c, cap_t, eps).detach()
    u_next = torch.where(stuck, torch.zeros_like(v), v)
    force = torch.where(stuck, tip_at_rest_coin + 0 * v, cap_t * regularised_slip(w - u_next, eps))
    return u_next, force


def material_from_pieces(pieces: dict, V: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """X(V) and Fy(V) of :meth:`TipContactModel.material_pieces` (float64; V inside their span)."""
    knots = torch.as_tensor(pieces["knots"], dtype=torch.float64)
    slope = torch.as_tensor(pieces["slope"], dtype=torch.float64)
    intercept = torch.as_tensor(pieces["intercept"], dtype=torch.float64)

    def raw(t):
        k = torch.clamp(torch.searchsorted(knots, t, right=True) - 1, 0, len(slope) - 1)
        return slope[k] * t.unsqueeze(-1) + intercept[k]
    t = (V.double() - pieces["mean"]) / pieces["scale"]
    rest = raw(torch.tensor([(0.0 - pieces["mean"]) / pieces["scale"]], dtype=torch.float64))[0, 0]
    out = raw(t)
    return pieces["stroke_scale"] * (out[..., 0] - rest), pieces["fy_mean"] + pieces["fy_scale"] * out[..., 1]


class TipFriction:
    """What the tip-contact kinds share (``f-coulomb`` here, ``f-memory`` in memory.py): φ =
    (m_c, μ_b, μ_t) read from datasets that carry μ_t and ε_v, one ε_v over the training
    setups, and a material network m of the voltage alone. Listed before
    :class:`~deapull.surrogate.models.base.Surrogate` in the bases."""

    phi_fields = ("mass_kg", "mu_b", "mu_t")

    def _init_tip(self, norm, input_range, outputs: int, hidden, layers, gravity_m_s2, slip_rate_reg_m_s, iterations):
        if not slip_rate_reg_m_s > 0:
            raise ValueError(f"slip_rate_reg_m_s must be positive, got {slip_rate_reg_m_s}")
        hparams = {"hidden": hidden, "layers": layers, "gravity_m_s2": gravity_m_s2,
                   "slip_rate_reg_m_s": slip_rate_reg_m_s, "iterations": iterations}
        Surrogate.__init__(self, norm, input_range, hparams)
        self.material = mlp(1, hidden, layers, outputs)
        self.gravity_m_s2, self.slip_rate_reg_m_s, self.iterations = gravity_m_s2, slip_rate_reg_m_s, iterations

    @classmethod
    def phi_of(cls, data) -> Phi:
        """m_c, μ_b and μ_t of ``data``'s coin; refuses a dataset without μ_t or ε_v."""
        require_tip_contact(data)
        return Phi.of(data)

    @classmethod
    def training_hparams(cls, config, train_sets: list) -> dict:
        for d in train_sets:
            require_tip_contact(d)
        # the model's ε_v is the setups' ramps' (the extra runs': a push solved at a wider one, whose coin
        # slides at hundreds of ε_v, is trained on at the ramps'; docs/surrogate.md)
        ramps = [d for d in train_sets if not d.extra] or train_sets
        eps = {d.slip_rate_reg_m_s for d in ramps}
        if len(eps) != 1:
            raise InputError(f"training setups were made with different friction regularisations {sorted(eps)} m/s; "
                             f"{cls.kind} needs one")
        eps = eps.pop()
        other = sorted({d.name for d in train_sets if d.extra and d.slip_rate_reg_m_s != eps})
        if other:
            log.warning("extra runs %s were made at another friction regularisation than the setups' %g m/s; "
                        "%s trains on them at %g m/s", ", ".join(other), eps, cls.kind, eps)
        return {"hidden": config.hidden, "layers": config.layers, "gravity_m_s2": train_sets[0].gravity_m_s2,
                "slip_rate_reg_m_s": eps}

    def material_pieces(self, v_lo: float, v_hi: float) -> dict:
        """m as the exact piecewise-affine function it is on [v_lo, v_hi] V (a fast path).

        m is a ReLU network of one input t = (V − mean)/scale (either tip kind), so each of its outputs is
        continuous and affine between the points where a hidden unit changes sign. Layer by
        layer, the units' pre-activations are affine on every interval between the kinks
        found so far (their slopes come from the activation pattern at the interval's
        midpoint), so their zeros inside an interval are the next kinks. On each final
        piece the output is o(t) = slope t + intercept, from o and its slope at the piece's
        midpoint, in float64: the same function as :meth:`material_response` up to round-off.

        Returns
        -------
        dict
            ``knots`` (K+1,) in t, increasing, spanning [v_lo, v_hi]; ``slope``,
            ``intercept`` (K, outputs) of the raw outputs on each piece (f-coulomb: 2, f-memory: 4); ``mean``, ``scale``
            of t; ``stroke_scale`` (X = stroke_scale (o_0(t) − o_0(t(0 V)))), ``fy_mean``,
            ``fy_scale`` (Fy = fy_mean + fy_scale o_1(t)). :func:`material_from_pieces`
            evaluates them.
        """
        linears = [layer for layer in self.material if isinstance(layer, torch.nn.Linear)]
        Ws = [layer.weight.detach().double().cpu().numpy() for layer in linears]
        bs = [layer.bias.detach().double().cpu().numpy() for layer in linears]
        mean, scale = float(self.in_mean[2]), float(self.in_std[2])
        knots = np.array([(min(v_lo, 0.0) - mean) / scale, (v_hi - mean) / scale])

        def affine(t, depth):
            """Pre-activation of layer ``depth`` and its slope in t at the points t (K,)."""
            h, dh = t[:, None], np.ones((len(t), 1))
            for j in range(depth):
                z, dz = h @ Ws[j].T + bs[j], dh @ Ws[j].T
                h, dh = np.where(z > 0, z, 0.0), np.where(z > 0, dz, 0.0)
            return h @ Ws[depth].T + bs[depth], dh @ Ws[depth].T

        for depth in range(1, len(Ws)):
            mid = 0.5 * (knots[:-1] + knots[1:])
            z, dz = affine(mid, depth - 1)
            with np.errstate(divide="ignore", invalid="ignore"):
                zero = mid[:, None] - z / dz
            inside = (dz != 0) & (zero > knots[:-1, None]) & (zero < knots[1:, None])
            knots = np.unique(np.concatenate([knots, zero[inside]]))
        mid = 0.5 * (knots[:-1] + knots[1:])
        out, slope = affine(mid, len(Ws) - 1)
        return {"knots": knots, "slope": slope, "intercept": out - slope * mid[:, None], "mean": mean,
                "scale": scale, "stroke_scale": float(self.s_std[0]), "fy_mean": float(self.z_mean[1]),
                "fy_scale": float(self.z_std[1])}


@register
class TipContactModel(TipFriction, Surrogate):
    """f = d∘m grounded in the FEM's contact mechanics (kind ``f-coulomb``).

    m (θ): an MLP 1 → ``layers``×``hidden`` ReLU → 2 of the voltage alone gives the DEA's
    material response at its tip: the stroke X(V) of the tip's contact point along x
    (X(0) = 0) and the pressing force Fy(V). In the FEM both depend on the voltage and hardly
    on the coin (Fy at equal V agrees across the eight setups to 0.1 %); feeding m the
    coin's state would tie it to the training coin's path instead.

    d (φ = (m_c, μ_b, μ_t)): the tip moves at w = (X(V_t+1) - X(V_t))/Δt and drags the coin
    with the FEM's rate-regularised Coulomb friction (ε_v from the dataset); the ground holds
    it with exact Coulomb stick/slip (:func:`tip_coin_step`). The onset of sliding, the lag
    of the coin behind the tip and the effect of a heavier or rougher coin all come out of d;
    z = (Fx, Fy) with Fx the friction the tip exerts.

    The rollout memory is (V, X) of the previous step; a rollout starts with the DEA at 0 V.

    Parameters
    ----------
    norm, input_range
        See :class:`~deapull.surrogate.models.base.Surrogate`.
    hidden, layers : int
    gravity_m_s2 : float
    slip_rate_reg_m_s : float
        ε_v of the tip–coin friction (the FEM scene's ``contact.slip_rate_regularisation_m_s``).
    iterations : int
        Iterations of the step's root solve.
    """

    kind = "f-coulomb"
    label = "f (tip contact)"
    physics = True

    #: outputs of m: the stroke and Fy (f-patch adds the patch's spread, softplus(o₂ − spread_shift))
    material_outputs = 2
    spread_shift = 0.0

    def __init__(self, norm: Normalisation, input_range: InputRange, hidden: int = 128, layers: int = 3,
                 gravity_m_s2: float = 9.8, slip_rate_reg_m_s: float = 1e-4, iterations: int = 40):
        self._init_tip(norm, input_range, self.material_outputs, hidden, layers, gravity_m_s2, slip_rate_reg_m_s,
                       iterations)

    def material_all(self, V: torch.Tensor):
        """m's outputs: the tip's stroke X(V) (m, X(0) = 0), pressing force Fy(V) (N) and the
        patch's slip spread β(V) (f-patch; None here)."""
        scaled = torch.stack([V, torch.zeros_like(V)], dim=-1).unsqueeze(-1)
        out = self.material((scaled - self.in_mean[2]) / self.in_std[2])
        stroke = self.s_std[0] * (out[..., 0, 0] - out[..., 1, 0])
        return stroke, self.z_mean[1] + self.z_std[1] * out[..., 0, 1], self.spread_of(out[..., 0, :])

    def material_response(self, V: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """m: the tip's stroke X(V) (m, X(0) = 0) and pressing force Fy(V) (N)."""
        return self.material_all(V)[:2]

    def spread_of(self, raw):
        """The patch's slip spread β from m's raw outputs (f-patch); None: a point contact."""
        return None

    def slip_eps(self, w, spread):
        """The tip friction's regularisation over a step: ε_v, widened to √(ε_v² + (β w)²) by
        the patch's spread β (f-patch)."""
        if spread is None:
            return self.slip_rate_reg_m_s
        return torch.sqrt(self.slip_rate_reg_m_s ** 2 + (spread.double() * w) ** 2)

    def init_memory(self, s0, a0):
        """(V, X) before the first step: the DEA at rest, 0 V."""
        return torch.zeros(s0.shape[:-1] + (2,), dtype=s0.dtype, device=s0.device)

    def patch_at(self, x, stroke_prev, spread):
        """(grip factor on μ_t Fy, spread β) of the patch that the coin at ``x`` meets: (1, β)
        here, functions of the coin's lag behind the tip in f-patch-lag."""
        return 1.0, spread

    def dynamics(self, s, a, stroke_prev, stroke, fy, phi: Phi, spread=None):
        """d: the next state and z = (Fx, Fy), in float64, from the tip's stroke over the step
        (and f-patch's spread β at the step's end)."""
        s, a = s.double(), a.double()
        grip, spread = self.patch_at(s[..., 0], stroke_prev, spread)
        phi = self._phi(phi, s, torch.float64)
        dt = a[..., 1]
        fy = fy.double()
        normal = torch.clamp(phi.mass_kg * self.gravity_m_s2 + fy, min=0.0)
        w = (stroke.double() - stroke_prev.double()) / dt
        u_next, fx = tip_coin_step(s[..., 1], w, phi.mu_t * torch.clamp(fy, min=0.0) * grip, phi.mu_b * normal,
                                   phi.mass_kg, dt, self.slip_eps(w, spread), self.iterations)
        return torch.stack([s[..., 0] + dt * u_next, u_next], dim=-1), torch.stack([fx, fy], dim=-1)

    def forward(self, s, a, v_prev, phi: Phi):
        """f(s, a; θ, φ) → (s', z) from the voltage ``v_prev`` before the step; ``phi`` is one
        coin or one per row."""
        stroke, fy, spread = self.material_all(torch.stack([v_prev, a[..., 0]], dim=-1))
        s_next, z = self.dynamics(s, a, stroke[..., 0], stroke[..., 1], fy[..., 1], phi,
                                  None if spread is None else spread[..., 1])
        return s_next.to(s.dtype), z.to(s.dtype)

    def step(self, s, a, memory=None, phi: Phi | None = None):
        if memory is None:
            memory = self.init_memory(s, a)
        stroke, fy, spread = self.material_all(a[..., 0])
        s_next, z = self.dynamics(s, a, memory[..., 1], stroke, fy, phi, spread)
        return s_next.to(s.dtype), z.to(s.dtype), torch.stack([a[..., 0], stroke.to(s.dtype)], dim=-1)

    def training_loss(self, batch: Transitions) -> torch.Tensor:
        s_next, z = self(batch.s, batch.a, batch.v_prev, batch.phi)
        return state_loss(self, s_next, z, batch)

    def native_kernel(self, phi: Phi) -> NativeKernel:
        """``deapull_rollout_tip``: norm = V mean and scale, x scale, Fy mean and scale;
        phys = m_c, μ_b, μ_t, g, ε_v, iterations."""
        n_layers, sizes, params = mlp_params(self.material)
        norm = np.array([self.in_mean[2].item(), self.in_std[2].item(), self.s_std[0].item(),
                         self.z_mean[1].item(), self.z_std[1].item()])
        phys = np.array([phi.value("mass_kg"), phi.value("mu_b"), phi.value("mu_t"), self.gravity_m_s2,
                         self.slip_rate_reg_m_s, self.iterations], dtype=np.float64)
        return NativeKernel("deapull_rollout_tip", (n_layers, sizes, params, norm, phys), forces=True)


@register
class TipPatchModel(TipContactModel):
    """f-coulomb with a tip patch whose points slide at different speeds (kind ``f-patch``).

    On the resolved contact the coin does not follow the tip at one speed: the patch's points
    move at different speeds (the underside stretches and the patch rolls toward the tip's
    edge), and the coin takes the speed at which their frictions balance the ground's. So the
    coin's share of the tip's speed falls with the friction margin r = μ_b N/(μ_t Fy) and,
    more and more, with the voltage (docs/surrogate.md: at 370 V C3 moves at 0.71 of the tip's
    speed, C5 at 0.42). One more output of m, the patch's spread β(V) ≥ 0, widens the tip
    friction's regularisation over a step to ε = √(ε_v² + (β w)²): the tip's pull on a coin
    moving at u is μ_t Fy s/√(s² + ε²), s = w − u, so a coin dragged at a steady margin r lags
    the tip by ε r/√(1 − r²) ≈ β w r/√(1 − r²), a share that grows with r as the FEM's does.
    β = 0 is f-coulomb. The spread is a property of the DEA (of V alone); only runs with
    different margins at the same V identify it apart from the stroke X. Trained on one coin it
    still carries a share that falls with the coin's speed to a coin of another margin: it is
    the f of the paper's one-coin sets (docs/surrogate.md, Table II).

    m: MLP 1 → ``layers``×``hidden`` ReLU → 3 (X, Fy, β = softplus(o₂ − ``spread_shift``)). No C
    rollout kernel: rollouts take the torch path; the MPC's compiled step
    (``control/native_mpc.c``) and the inference's compiled prediction carry β.
    """

    kind = "f-patch"
    label = "f (tip patch)"
    material_outputs = 3
    #: β = softplus(o₂ − spread_shift): β ≈ 0.13 for a fresh network's o₂ ≈ 0
    spread_shift = 2.0
    native_kernel = None

    def spread_of(self, raw):
        return torch.nn.functional.softplus(raw[..., 2] - self.spread_shift)


@register
class TipPatchLagModel(TipPatchModel):
    """f-patch whose patch also depends on how far the coin lags behind the tip (kind
    ``f-patch-lag``).

    The FEM's patch probe (docs/surrogate.md, "The patch probe") shows that the patch a coin
    meets is close to a function of V and of the coin's lag ℓ behind the tip's free end: a coin
    that lags more meets less drag per pressing force. So d scales the tip's grip μ_t Fy by
    exp(λ ℓ) and the spread β by exp(κ ℓ), with ℓ = |X| − |x| in mm (the stroke before the
    step less the coin's travel). λ and κ are two learned scalars; zero is f-patch. Several
    coins identify them (f_a: C3..C7); on one coin's ramp ℓ follows V, and m absorbs them.

    No compiled path: the compiled MPC and inference would need ℓ's terms in x. It plans and
    infers on the torch path (:class:`deapull.control.adapters.TipPatchLagAdapter`).
    """

    kind = "f-patch-lag"
    label = "f (tip patch, lag)"
    training_coins = 2

    @classmethod
    def training_hparams(cls, config, train_sets: list) -> dict:
        margins = {(d.mu_t, d.mu_b) for d in train_sets}
        if len(margins) < cls.training_coins:
            log.warning("f-patch-lag trained on coins of %d friction pair(s) %s: the lag terms are not identified "
                        "(on one coin's ramp the lag follows V); train on coins of different μ_t/μ_b",
                        len(margins), sorted(margins))
        return super().training_hparams(config, train_sets)

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        # in m's dtype: rollouts take theirs from the first parameter
        self.lag_grip = torch.nn.Parameter(torch.zeros(()))      # λ, per mm of lag
        self.lag_spread = torch.nn.Parameter(torch.zeros(()))    # κ, per mm of lag

    @staticmethod
    def lag_mm(x, stroke_prev):
        """ℓ: how far (mm) the coin at ``x`` is behind the tip's stroke before the step."""
        return (stroke_prev.double().abs() - x.double().abs()) * 1e3

    def patch_at(self, x, stroke_prev, spread):
        """(grip factor exp(λ ℓ), spread β exp(κ ℓ)) of the patch that the coin at ``x`` meets."""
        lag = self.lag_mm(x, stroke_prev)
        grip = torch.exp(self.lag_grip.double() * lag)
        return grip, None if spread is None else spread.double() * torch.exp(self.lag_spread.double() * lag)
