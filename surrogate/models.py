"""The surrogate models: physics-informed f = d∘m (two dynamics laws) and two black boxes.

Every model takes and returns physical quantities (SI); the normalisation of the training
data lives in the model as buffers, so a model is one self-contained ``nn.Module``:

* :class:`PhysicsModel` — the paper's f(s, a; θ, φ) = d(m(s, a; θ), s, a; φ) (eqs. 1–2):
  a material network m (eq. 7: MLP 4 → 3×128 ReLU → 2) estimates the DEA's forces
  z = (Fx, Fy) and a dynamics law d moves the coin, with φ = (m_c, μ_b) as parameters.
  ``law="paper"`` is eqs. 4–6 (threshold voltage V^T, contact loss, frictional decay,
  motion only along the pull);
  ``law="coulomb"`` is a smoothed Coulomb stick/slip step without V^T.
* :class:`NNBaseline` — a black-box MLP (s, a) → s'.
* :class:`LSTMBaseline` — a black-box LSTM over the last ``window`` (s, a) pairs → s'.

All models share one step interface for rollouts, ``step(s, a, memory) -> (s', z, memory)``
(``z`` is None for the black boxes, ``memory`` None for memoryless models), and one
training interface, ``training_loss(batch)``.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
from torch import nn
from torch.nn import functional as F

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


def friction_release(u_trial: torch.Tensor, u_cap: torch.Tensor, smoothing: float) -> torch.Tensor:
    """Velocity after a friction impulse that may stop the coin but never reverses it.

    ``sign(u*) max(|u*| - c, 0)``: the trial velocity u* = u + Δt F/m_c loses at most
    c = Δt F_μ/m_c. With ``smoothing`` τ > 0 (m/s) it is the smooth odd function
    τ [softplus((u* - c)/τ) - softplus((-u* - c)/τ)], which differs from the exact clamp
    by at most τ ln 2, is exactly 0 at u* = 0, and has useful gradients across stick/slip.
    """
    if smoothing > 0:
        return smoothing * (F.softplus((u_trial - u_cap) / smoothing) - F.softplus((-u_trial - u_cap) / smoothing))
    return torch.sign(u_trial) * torch.relu(u_trial.abs() - u_cap)


def coulomb_dynamics(z, s, a, mass_kg, mu_b, gravity, smoothing: float) -> torch.Tensor:
    """d, Coulomb variant: one backward-Euler step of the coin with ground stick/slip.

    m_c (u' - u) = Δt (Fx - f_b),  f_b ∈ μ_b N [-1, 1],  N = max(m_c g + Fy, 0),
    x' = x + Δt u'. The friction f_b is the force that stops the coin within the step,
    clamped to the Coulomb cone (smoothed by :func:`friction_release`); no threshold
    voltage is needed: the coin sticks exactly while |m_c u + Δt Fx| ≤ Δt μ_b N.
    """
    x, u, dt = s[..., 0], s[..., 1], a[..., 1]
    fx, fy = z[..., 0], z[..., 1]
    normal = torch.clamp(mass_kg * gravity + fy, min=0.0)
    u_next = friction_release(u + dt * fx / mass_kg, dt * mu_b * normal / mass_kg, smoothing)
    return torch.stack([x + dt * u_next, u_next], dim=-1)


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
    """f = d∘m: material network m (θ) and coin dynamics d (φ = (m_c, μ_b)).

    Parameters
    ----------
    norm, input_range
        See :class:`Surrogate`.
    law : {"paper", "coulomb"}
        Dynamics d: :func:`paper_dynamics` (kind ``f``) or :func:`coulomb_dynamics`
        (kind ``f-coulomb``).
    hidden, layers : int
        Material network width and depth (paper: 128, 3).
    gravity_m_s2 : float
    v_contact_loss_V : float
        Paper law: voltage from which the DEA has lost the coin (inf: never).
    smoothing_m_s : float
        Coulomb law: velocity scale τ of the smoothed stick/slip (0: exact clamp).
    mass_kg, mu_b, v_threshold_V : float
        The setup simulated by :meth:`step` (change it with :meth:`set_setup`).
    """

    def __init__(self, norm: Normalisation, input_range: InputRange, law: str = "coulomb", hidden: int = 128,
                 layers: int = 3, gravity_m_s2: float = 9.8, v_contact_loss_V: float = math.inf,
                 smoothing_m_s: float = 1e-6, mass_kg: float = 1.36e-3, mu_b: float = 0.2,
                 v_threshold_V: float = math.nan):
        if law not in ("paper", "coulomb"):
            raise ValueError(f"law must be 'paper' or 'coulomb', not {law!r}")
        hparams = {"law": law, "hidden": hidden, "layers": layers, "gravity_m_s2": gravity_m_s2,
                   "v_contact_loss_V": v_contact_loss_V, "smoothing_m_s": smoothing_m_s}
        super().__init__(norm, input_range, hparams)
        self.kind = "f" if law == "paper" else "f-coulomb"
        self.law = law
        self.material = mlp(4, hidden, layers, 2)
        self.mass_kg = nn.Parameter(torch.tensor(mass_kg), requires_grad=False)
        self.mu_b = nn.Parameter(torch.tensor(mu_b), requires_grad=False)
        self.register_buffer("v_threshold_V", torch.tensor(v_threshold_V))
        self.gravity_m_s2, self.v_contact_loss_V, self.smoothing_m_s = gravity_m_s2, v_contact_loss_V, smoothing_m_s

    def set_setup(self, mass_kg: float, mu_b: float, v_threshold_V: float = math.nan) -> None:
        """Set φ = (m_c, μ_b) and V^T to those of the setup to simulate."""
        if self.law == "paper" and not v_threshold_V > 0:
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
        if self.law == "paper":
            return paper_dynamics(z, s, a, mass_kg, mu_b, self.gravity_m_s2, v_threshold, self.v_contact_loss_V)
        return coulomb_dynamics(z, s, a, mass_kg, mu_b, self.gravity_m_s2, self.smoothing_m_s)

    def forward(self, s: torch.Tensor, a: torch.Tensor, phi: torch.Tensor | None = None):
        """f(s, a; θ, φ) → (s', z). ``phi`` (..., 3) = (m_c, μ_b, V^T) per row overrides the
        model's own setup (used in training, where rows come from several setups)."""
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
    if kind in ("f", "f-coulomb"):
        hparams.setdefault("law", "paper" if kind == "f" else "coulomb")
        return PhysicsModel(norm, input_range, **hparams)
    if kind == "nn":
        return NNBaseline(norm, input_range, **hparams)
    if kind == "lstm":
        return LSTMBaseline(norm, input_range, **hparams)
    raise ValueError(f"unknown model kind {kind!r}; choose one of {', '.join(KINDS)}")
