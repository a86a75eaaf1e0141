"""The surrogate models: physics-informed f = d∘m (two dynamics laws) and two black boxes.

Every model takes and returns physical quantities (SI); the normalisation of the training
data lives in the model as buffers, so a model is one self-contained ``nn.Module``:

* :class:`PhysicsModel` (kind ``f``) — the paper's f(s, a; θ, φ) = d(m(s, a; θ), s, a; φ)
  (eqs. 1–2): a material network m (eq. 7: MLP 4 → 3×128 ReLU → 2) estimates the DEA's
  forces z = (Fx, Fy) and the paper's law d (eqs. 4–6: threshold voltage V^T, contact
  loss, frictional decay, motion only along the pull) moves the coin, φ = (m_c, μ_b).
* :class:`TipContactModel` (kind ``f-coulomb``) — f = d∘m grounded in the FEM's contact
  mechanics: m (MLP 1 → 3×128 ReLU → 2) maps the voltage to the DEA tip's stroke X(V) and
  pressing force Fy(V); d moves the coin between two Coulomb contacts — the tip dragging it
  with the FEM's rate-regularised friction μ_t, the ground holding it with exact stick/slip
  μ_b — with φ = (m_c, μ_b, μ_t). No V^T is needed.
* :class:`NNBaseline` — a black-box MLP (s, a) → s'.
* :class:`LSTMBaseline` — a black-box LSTM over the last ``window`` (s, a) pairs → s'.

All models share one step interface for rollouts, ``step(s, a, memory) -> (s', z, memory)``
(``z`` is None for the black boxes, ``memory`` None for memoryless models; the LSTM keeps
its window, the tip-contact model the voltage and stroke of the previous step), one
training interface, ``training_loss(batch)``, and physics models one way to pick the coin,
``set_setup(mass_kg, mu_b, v_threshold_V, mu_t)``.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
from torch import nn

from surrogate.data import Transitions

KINDS = ("f", "f-coulomb", "nn", "lstm")
INPUTS = ("x", "u", "V", "dt")
INPUT_UNITS = ("m", "m/s", "V", "s")


@dataclass(frozen=True)
class Normalisation:
    """Means and scales of the training data (each a list of floats, SI units).

    Attributes
    ----------
    in_mean, in_std : list of float
        Of the inputs (x, u, V, Δt).
    z_mean, z_std : list of float
        Of the forces (Fx, Fy).
    s_std : list of float
        Of the states (x, u): scale of the state error in the loss (eq. 3).
    ds_std : list of float
        Of the one-step state changes (x' - x, u' - u): output scale of the black boxes.
    """

    in_mean: list
    in_std: list
    z_mean: list
    z_std: list
    s_std: list
    ds_std: list

    @classmethod
    def from_transitions(cls, tr: Transitions) -> "Normalisation":
        inputs = torch.cat([tr.s, tr.a], dim=1).double()
        z, s, ds = tr.z.double(), tr.s.double(), (tr.s_next - tr.s).double()
        return cls(in_mean=inputs.mean(0).tolist(), in_std=_scale(inputs),
                   z_mean=z.mean(0).tolist(), z_std=_scale(z), s_std=_scale(s), ds_std=_scale(ds))

    def to_dict(self) -> dict:
        return asdict(self)


def _scale(values: torch.Tensor) -> list:
    """Standard deviation per column; a constant column gets |mean| (or 1 when that is 0)."""
    std, mean = values.std(0, unbiased=False), values.mean(0).abs()
    return torch.where(std > 0, std, torch.where(mean > 0, mean, torch.ones_like(mean))).tolist()


@dataclass(frozen=True)
class InputRange:
    """The box of inputs (x, u, V, Δt) seen in training, with a relative tolerance.

    An input counts as outside when it leaves [low - tol·span, high + tol·span].
    """

    low: list
    high: list
    tolerance: float = 0.05

    @classmethod
    def from_transitions(cls, tr: Transitions, tolerance: float = 0.05) -> "InputRange":
        inputs = torch.cat([tr.s, tr.a], dim=1).double()
        return cls(low=inputs.min(0).values.tolist(), high=inputs.max(0).values.tolist(), tolerance=tolerance)

    def bounds(self) -> tuple[list, list]:
        """Lower and upper admissible value of each input."""
        span = [h - lo for lo, h in zip(self.low, self.high)]
        return ([lo - self.tolerance * w for lo, w in zip(self.low, span)],
                [h + self.tolerance * w for h, w in zip(self.high, span)])

    def to_dict(self) -> dict:
        return {"inputs": list(INPUTS), "units": list(INPUT_UNITS), **asdict(self)}


def mlp(n_in: int, hidden: int, layers: int, n_out: int) -> nn.Sequential:
    """Fully connected net: ``layers`` hidden layers of ``hidden`` ReLU units."""
    mods, width = [], n_in
    for _ in range(layers):
        mods += [nn.Linear(width, hidden), nn.ReLU()]
        width = hidden
    mods.append(nn.Linear(width, n_out))
    return nn.Sequential(*mods)


class Surrogate(nn.Module):
    """Base class: the training data's normalisation and input range, as buffers.

    Parameters
    ----------
    norm : Normalisation
    input_range : InputRange
    hparams : dict
        Hyper-parameters that rebuild the model (saved in its JSON).
    """

    kind = ""
    window = 1

    def __init__(self, norm: Normalisation, input_range: InputRange, hparams: dict):
        super().__init__()
        self.norm, self.input_range, self.hparams = norm, input_range, dict(hparams)
        for name, values in norm.to_dict().items():
            self.register_buffer(name, torch.tensor(values, dtype=torch.float32))

    def normalised_inputs(self, s: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        """(x, u, V, Δt) → zero-mean, unit-scale network inputs."""
        return (torch.cat([s, a], dim=-1) - self.in_mean) / self.in_std

    def init_memory(self, s0: torch.Tensor, a0: torch.Tensor):
        """The rollout memory before the first step (None for memoryless models)."""
        return None

    def step(self, s: torch.Tensor, a: torch.Tensor, memory=None):
        """One transition: ``(s', z, memory')`` from state s (..., 2) and action a (..., 2)."""
        raise NotImplementedError

    def training_loss(self, batch: Transitions) -> torch.Tensor:
        """The loss minimised in training, on normalised quantities."""
        raise NotImplementedError


def paper_dynamics(z, s, a, mass_kg, mu_b, gravity, v_threshold, v_contact_loss: float) -> torch.Tensor:
    """d, the paper's law (eqs. 4–6): m_c A = Fx - F_μ along the pull (-x), with a
    voltage-ramped friction.

    The paper writes eq. 5 in magnitudes along the pulling direction: the DEA pulls with
    max(-Fx, 0) and friction F_μ = μ_b (Fy + m_c g) for V ≥ V^T, μ_b (V/V^T)(Fy + m_c g)
    below (eq. 6). For V ≥ ``v_contact_loss`` the DEA has lost the coin (Fx = Fy = 0); at
    V = 0 the DEA is off (no pull) and a moving coin decays under kinetic friction.
    Friction can stop the coin but never drive it, so the coin moves only toward -x:
    u' = -max(-u + Δt (pull - F_μ)/m_c, 0) and x' = x + Δt u'.
    """
    x, u, V, dt = s[..., 0], s[..., 1], a[..., 0], a[..., 1]
    fx, fy = z[..., 0], z[..., 1]
    contact = V < v_contact_loss
    pull = torch.where(contact & (V > 0), torch.relu(-fx), torch.zeros_like(fx))
    fy = torch.where(contact, fy, torch.zeros_like(fy))
    ramp = torch.where(V > 0, torch.clamp(V / v_threshold, max=1.0), torch.ones_like(V))
    friction = mu_b * ramp * torch.clamp(fy + mass_kg * gravity, min=0.0)
    u_next = -torch.relu(-u + dt * (pull - friction) / mass_kg)
    return torch.stack([x + dt * u_next, u_next], dim=-1)


class PhysicsModel(Surrogate):
    """The paper's f = d∘m: material network m (θ) and the paper's law d (φ = (m_c, μ_b)).

    Parameters
    ----------
    norm, input_range
        See :class:`Surrogate`.
    law : {"paper"}
        Dynamics d: :func:`paper_dynamics` (kind ``f``).
    hidden, layers : int
        Material network width and depth (paper: 128, 3).
    gravity_m_s2 : float
    v_contact_loss_V : float
        Voltage from which the DEA has lost the coin (inf: never).
    mass_kg, mu_b, v_threshold_V : float
        The setup simulated by :meth:`step` (change it with :meth:`set_setup`).
    """

    kind = "f"

    def __init__(self, norm: Normalisation, input_range: InputRange, law: str = "paper", hidden: int = 128,
                 layers: int = 3, gravity_m_s2: float = 9.8, v_contact_loss_V: float = math.inf,
                 mass_kg: float = 1.36e-3, mu_b: float = 0.2, v_threshold_V: float = math.nan):
        if law != "paper":
            raise ValueError(f"law must be 'paper', not {law!r} (the Coulomb variant is TipContactModel)")
        hparams = {"law": law, "hidden": hidden, "layers": layers, "gravity_m_s2": gravity_m_s2,
                   "v_contact_loss_V": v_contact_loss_V}
        super().__init__(norm, input_range, hparams)   # 'law' stays in hparams: saved models name it
        self.material = mlp(4, hidden, layers, 2)
        self.mass_kg = nn.Parameter(torch.tensor(mass_kg), requires_grad=False)
        self.mu_b = nn.Parameter(torch.tensor(mu_b), requires_grad=False)
        self.register_buffer("v_threshold_V", torch.tensor(v_threshold_V))
        self.gravity_m_s2, self.v_contact_loss_V = gravity_m_s2, v_contact_loss_V

    def set_setup(self, mass_kg: float, mu_b: float, v_threshold_V: float = math.nan, mu_t: float = math.nan) -> None:
        """Set φ = (m_c, μ_b) and V^T to those of the setup to simulate (μ_t is not used)."""
        if not v_threshold_V > 0:
            raise ValueError(f"the paper's law needs a positive threshold voltage V^T, got {v_threshold_V}")
        with torch.no_grad():
            self.mass_kg.fill_(mass_kg)
            self.mu_b.fill_(mu_b)
            self.v_threshold_V.fill_(v_threshold_V)

    def forces(self, s: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        """m: the DEA's force on the coin z = (Fx, Fy) in N."""
        return self.z_mean + self.z_std * self.material(self.normalised_inputs(s, a))

    def dynamics(self, z, s, a, mass_kg, mu_b, v_threshold) -> torch.Tensor:
        """d: the next state from forces, state, action and φ (broadcast against the batch)."""
        return paper_dynamics(z, s, a, mass_kg, mu_b, self.gravity_m_s2, v_threshold, self.v_contact_loss_V)

    def forward(self, s: torch.Tensor, a: torch.Tensor, phi: torch.Tensor | None = None):
        """f(s, a; θ, φ) → (s', z). ``phi`` (..., 4) = (m_c, μ_b, V^T, μ_t) per row overrides
        the model's own setup (used in training, where rows come from several setups)."""
        z = self.forces(s, a)
        if phi is None:
            mass, mu_b, vt = self.mass_kg, self.mu_b, self.v_threshold_V
        else:
            mass, mu_b, vt = phi[..., 0], phi[..., 1], phi[..., 2]
        return self.dynamics(z, s, a, mass, mu_b, vt), z

    def step(self, s, a, memory=None):
        s_next, z = self(s, a)
        return s_next, z, None

    def training_loss(self, batch: Transitions) -> torch.Tensor:
        """Eq. 3: mean squared error of z and of s', each normalised by its scale."""
        s_next, z = self(batch.s, batch.a, batch.phi)
        return (((z - batch.z) / self.z_std) ** 2).mean() + (((s_next - batch.s_next) / self.s_std) ** 2).mean()


def regularised_slip(v: torch.Tensor, eps: float) -> torch.Tensor:
    """The FEM's rate-regularised Coulomb factor s/√(s² + ε²) ∈ (-1, 1) of a slip rate s."""
    return v / torch.sqrt(v * v + eps * eps)


def tip_coin_step(u, w, cap_t, cap_b, mass_kg, dt, eps: float, iterations: int = 40):
    """d of the tip-contact model: one backward-Euler step of the coin between two contacts.

    The coin (mass m_c, velocity u) is dragged by the DEA tip moving at w with the FEM's
    rate-regularised friction T = μ_t Fy (w - u')/√((w - u')² + ε²) and held by the ground
    with exact Coulomb stick/slip, |B| ≤ μ_b N:

        m_c (u' - u) / Δt = T(u') - B,   B ∈ μ_b N Sgn(u').

    The right side decreases in u', so the step has one solution: the coin sticks (u' = 0)
    when the tip's pull at u' = 0 plus the coin's momentum stays inside the ground's cone;
    otherwise the sign of u' is known and a bracketed Newton solve finds it. The solve runs
    without gradients, then one Newton correction with them gives the gradients of the
    exact root (implicit differentiation) with respect to every input.

    Parameters
    ----------
    u, w : torch.Tensor
        Coin velocity before the step and tip velocity over it (m/s).
    cap_t, cap_b : torch.Tensor
        μ_t Fy and μ_b N (N), non-negative.
    mass_kg, dt : torch.Tensor or float
    eps : float
        Slip-rate regularisation ε (m/s), > 0.
    iterations : int
        Most Newton/bisection iterations (they stop once no row changes; a handful suffice).

    Returns
    -------
    (u_next, T) : tuple of torch.Tensor
        The coin velocity after the step and the tip's force on the coin along x (N).
    """
    c = mass_kg / dt
    tip_at_rest_coin = cap_t * regularised_slip(w, eps)
    ground_reaction = tip_at_rest_coin + c * u
    stuck = ground_reaction.abs() <= cap_b
    sign = torch.where(ground_reaction > 0, torch.ones_like(u), -torch.ones_like(u))

    def residual(v):
        return c * (v - u) - cap_t * regularised_slip(w - v, eps) + sign * cap_b

    def slope(v):
        return c + cap_t * eps * eps / ((w - v) ** 2 + eps * eps) ** 1.5

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
            r = residual(v)
            lo, hi = torch.where(r < 0, v, lo), torch.where(r >= 0, v, hi)
            step = r / slope(v)
            # bisect where Newton leaves the bracket or does not halve its last change
            bisect = (v - step < lo) | (v - step > hi) | (2 * step.abs() > change.abs())
            v, previous = torch.where(bisect, 0.5 * (lo + hi), v - step), v
            change = v - previous
            if bool(torch.all(change.abs() <= 1e-13 * (v.abs() + eps))):
                break
    v = v - residual(v) / slope(v).detach()
    u_next = torch.where(stuck, torch.zeros_like(v), v)
    force = torch.where(stuck, tip_at_rest_coin + 0 * v, cap_t * regularised_slip(w - u_next, eps))
    return u_next, force


class TipContactModel(Surrogate):
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
        See :class:`Surrogate`.
    hidden, layers : int
    gravity_m_s2 : float
    slip_rate_reg_m_s : float
        ε_v of the tip–coin friction (the FEM scene's ``contact.slip_rate_regularisation_m_s``).
    iterations : int
        Iterations of the step's root solve.
    mass_kg, mu_b, mu_t : float
        The setup simulated by :meth:`step` (change it with :meth:`set_setup`).
    """

    kind = "f-coulomb"

    def __init__(self, norm: Normalisation, input_range: InputRange, hidden: int = 128, layers: int = 3,
                 gravity_m_s2: float = 9.8, slip_rate_reg_m_s: float = 1e-4, iterations: int = 40,
                 mass_kg: float = 1.36e-3, mu_b: float = 0.2, mu_t: float = 0.5):
        if not slip_rate_reg_m_s > 0:
            raise ValueError(f"slip_rate_reg_m_s must be positive, got {slip_rate_reg_m_s}")
        hparams = {"hidden": hidden, "layers": layers, "gravity_m_s2": gravity_m_s2,
                   "slip_rate_reg_m_s": slip_rate_reg_m_s, "iterations": iterations}
        super().__init__(norm, input_range, hparams)
        self.material = mlp(1, hidden, layers, 2)
        self.mass_kg = nn.Parameter(torch.tensor(mass_kg), requires_grad=False)
        self.mu_b = nn.Parameter(torch.tensor(mu_b), requires_grad=False)
        self.mu_t = nn.Parameter(torch.tensor(mu_t), requires_grad=False)
        self.gravity_m_s2, self.slip_rate_reg_m_s, self.iterations = gravity_m_s2, slip_rate_reg_m_s, iterations

    def set_setup(self, mass_kg: float, mu_b: float, v_threshold_V: float = math.nan, mu_t: float = math.nan) -> None:
        """Set φ = (m_c, μ_b, μ_t) to those of the setup to simulate (V^T is not used)."""
        if not mu_t >= 0:
            raise ValueError(f"the tip-contact model needs the tip-coin friction μ_t >= 0, got {mu_t}")
        with torch.no_grad():
            self.mass_kg.fill_(mass_kg)
            self.mu_b.fill_(mu_b)
            self.mu_t.fill_(mu_t)

    def material_response(self, V: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """m: the tip's stroke X(V) (m, X(0) = 0) and pressing force Fy(V) (N)."""
        scaled = torch.stack([V, torch.zeros_like(V)], dim=-1).unsqueeze(-1)
        out = self.material((scaled - self.in_mean[2]) / self.in_std[2])
        stroke = self.s_std[0] * (out[..., 0, 0] - out[..., 1, 0])
        return stroke, self.z_mean[1] + self.z_std[1] * out[..., 0, 1]

    def init_memory(self, s0, a0):
        """(V, X) before the first step: the DEA at rest, 0 V."""
        return torch.zeros(s0.shape[:-1] + (2,), dtype=s0.dtype, device=s0.device)

    def dynamics(self, s, a, stroke_prev, stroke, fy, mass_kg, mu_b, mu_t):
        """d: the next state and z = (Fx, Fy), in float64, from the tip's stroke over the step."""
        s, a = s.double(), a.double()
        dt = a[..., 1]
        fy = fy.double()
        normal = torch.clamp(mass_kg * self.gravity_m_s2 + fy, min=0.0)
        w = (stroke.double() - stroke_prev.double()) / dt
        u_next, fx = tip_coin_step(s[..., 1], w, mu_t * torch.clamp(fy, min=0.0), mu_b * normal, mass_kg, dt,
                                   self.slip_rate_reg_m_s, self.iterations)
        return torch.stack([s[..., 0] + dt * u_next, u_next], dim=-1), torch.stack([fx, fy], dim=-1)

    def forward(self, s, a, v_prev, phi=None):
        """f(s, a; θ, φ) → (s', z) from the voltage ``v_prev`` before the step; ``phi``
        (..., 4) = (m_c, μ_b, V^T, μ_t) per row overrides the model's own setup."""
        stroke, fy = self.material_response(torch.stack([v_prev, a[..., 0]], dim=-1))
        if phi is None:
            mass, mu_b, mu_t = self.mass_kg.double(), self.mu_b.double(), self.mu_t.double()
        else:
            phi = phi.double()
            mass, mu_b, mu_t = phi[..., 0], phi[..., 1], phi[..., 3]
        s_next, z = self.dynamics(s, a, stroke[..., 0], stroke[..., 1], fy[..., 1], mass, mu_b, mu_t)
        return s_next.to(s.dtype), z.to(s.dtype)

    def step(self, s, a, memory=None):
        if memory is None:
            memory = self.init_memory(s, a)
        stroke, fy = self.material_response(a[..., 0])
        mass, mu_b, mu_t = self.mass_kg.double(), self.mu_b.double(), self.mu_t.double()
        s_next, z = self.dynamics(s, a, memory[..., 1], stroke, fy, mass, mu_b, mu_t)
        return s_next.to(s.dtype), z.to(s.dtype), torch.stack([a[..., 0], stroke.to(s.dtype)], dim=-1)

    def training_loss(self, batch: Transitions) -> torch.Tensor:
        """Eq. 3: mean squared error of z and of s', each normalised by its scale."""
        s_next, z = self(batch.s, batch.a, batch.v_prev, batch.phi)
        return (((z - batch.z) / self.z_std) ** 2).mean() + (((s_next - batch.s_next) / self.s_std) ** 2).mean()


class NNBaseline(Surrogate):
    """Black box s' = s + σ_Δs · MLP((s, a) normalised): no physics, no φ."""

    kind = "nn"

    def __init__(self, norm: Normalisation, input_range: InputRange, hidden: int = 128, layers: int = 3):
        super().__init__(norm, input_range, {"hidden": hidden, "layers": layers})
        self.net = mlp(4, hidden, layers, 2)

    def forward(self, s: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        return s + self.ds_std * self.net(self.normalised_inputs(s, a))

    def step(self, s, a, memory=None):
        return self(s, a), None, None

    def training_loss(self, batch: Transitions) -> torch.Tensor:
        target = (batch.s_next - batch.s) / self.ds_std
        return ((self.net(self.normalised_inputs(batch.s, batch.a)) - target) ** 2).mean()


class LSTMBaseline(Surrogate):
    """Black box s' = s + σ_Δs · head(LSTM over the last ``window`` normalised (s, a) pairs).

    The window is re-read at every step (an ``window``-step recurrence, the paper's 8);
    at the start of a run it is padded by repeating the first pair.
    """

    kind = "lstm"

    def __init__(self, norm: Normalisation, input_range: InputRange, hidden: int = 128, window: int = 8):
        super().__init__(norm, input_range, {"hidden": hidden, "window": window})
        self.window = window
        self.lstm = nn.LSTM(4, hidden, batch_first=True)
        self.head = nn.Linear(hidden, 2)

    def increment(self, window: torch.Tensor) -> torch.Tensor:
        """Normalised state change from a window (B, W, 4) of raw (x, u, V, Δt)."""
        out, _ = self.lstm((window - self.in_mean) / self.in_std)
        return self.head(out[:, -1])

    def init_memory(self, s0, a0):
        return torch.cat([s0, a0], dim=-1).unsqueeze(1).expand(-1, self.window - 1, -1)

    def step(self, s, a, memory=None):
        window = torch.cat([memory, torch.cat([s, a], dim=-1).unsqueeze(1)], dim=1)
        return s + self.ds_std * self.increment(window), None, window[:, 1:]

    def training_loss(self, batch: Transitions) -> torch.Tensor:
        target = (batch.s_next - batch.s) / self.ds_std
        return ((self.increment(batch.window) - target) ** 2).mean()


def build(kind: str, norm: Normalisation, input_range: InputRange, hparams: dict | None = None) -> Surrogate:
    """A fresh model of ``kind`` (one of :data:`KINDS`) with hyper-parameters ``hparams``."""
    hparams = dict(hparams or {})
    if kind == "f":
        return PhysicsModel(norm, input_range, **hparams)
    if kind == "f-coulomb":
        return TipContactModel(norm, input_range, **hparams)
    if kind == "nn":
        return NNBaseline(norm, input_range, **hparams)
    if kind == "lstm":
        return LSTMBaseline(norm, input_range, **hparams)
    raise ValueError(f"unknown model kind {kind!r}; choose one of {', '.join(KINDS)}")
