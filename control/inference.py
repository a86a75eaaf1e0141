"""Online inference of the coin's φ during control (paper Algorithm 2, lines 6–11).

(Longer than ~500 lines on purpose: the replay buffer, the predictor, both optimisers and the
identifiability report work on one estimate; a split is planned with the capability registry.)

Every control step adds the observed transition to a replay buffer; every update draws a
batch of 256 transitions and takes one Adam step on log φ to minimise the one-step
prediction error of the model f_a (eq. 9), the network θ fixed. The MPC reads the current
φ (:attr:`OnlineInference.phi`) before each plan.

What a transition holds. The controller observes the coin's position x̃ (noisy) and the
voltage it applied, not the velocity. The model's step is backward Euler,
x_{t+1} = x_t + Δt u_{t+1}, so the velocity is the difference of consecutive positions,
u_t = (x̃_t − x̃_{t−1})/Δt (exact without noise; u_0 = 0, the coin starts at rest). A
transition is (x̃_{t−1}, x̃_t, V_t, V_{t+1}) with the target x̃_{t+1}, and the loss is

    L(φ) = mean_batch ((x̂_{t+1}(φ) − x̃_{t+1}) / s)²,   s = ``residual_scale_m``,

the paper's (s_{t+1} − ŝ_{t+1})² on the position, scaled so that Adam's steps do not
depend on units. The voltage-only parts of f_a (the material network: the tip's stroke and
pressing force, or the paper model's forces) are evaluated once per transition when it is
added, since θ is fixed.

Initial values: m_c = 0.001 g (the paper's); μ_b = 0.15 and μ_t = 0.4, below every setup's
truth (μ_b 0.20–0.25, μ_t 0.50–0.55), so that no episode starts at its plant's answer (the
paper starts μ_b at 0.2, which is C1–C4's own value: planning then needs no inference);
V^T (paper model) from 150 V. Each field is optimised as log φ, so it stays positive and
Adam's learning rate is a relative step (``lr`` = 0.05: about 5 % per update).

Identifiability (:func:`identifiability`): the sensitivity of the predicted positions to
each log φ over the buffer and the Fisher information of the position observations with
noise σ, which give the Cramér–Rao bound on each parameter's relative error.
"""
from __future__ import annotations

import copy
import functools
import logging
import math
import statistics
from dataclasses import dataclass, field

import numpy as np
import torch

from deapull import scene as scenes
from deapull.control import native
from deapull.control.adapters import adapter, capabilities
from deapull.errors import InputError
from deapull.surrogate.phi import FIELDS, Phi

log = logging.getLogger(__name__)

#: the initial values: the paper's m_c = 0.001 g; μ_b, μ_t below every setup's truth
INITIAL = {"mass_kg": 1e-6, "mu_b": 0.15, "mu_t": 0.4, "v_threshold_V": 150.0}
OPTIMIZERS = ("adam", "lm")
#: where the one-step loss and its Jacobian are evaluated (:attr:`InferenceConfig.engine`)
ENGINES = ("auto", "native", "torch")
#: the box each field is kept in while inferred (SI units), physical: a coin from the paper's
#: start (0.001 g) to 100 g; dry friction coefficients of elastomer and steel pairs from 0.01 to 2
BOUNDS = {"mass_kg": (1e-6, 0.1), "mu_b": (1e-2, 2.0), "mu_t": (1e-2, 2.0), "v_threshold_V": (1.0, 1e4)}
#: a stated log-normal prior over the design card's coin family (field: (median, std of log)):
#: coins of the scenes' geometry at ρ 7.7–7.8 g/cm³ weigh 1.36–1.38 g, μ_b 0.20–0.25,
#: μ_t 0.50–0.55; each widened to a factor 2 at one standard deviation (log std ln 2).
#: ``InferenceConfig(prior=COIN_PRIOR)`` (``deapull control --phi-prior coins``) makes the
#: inference a MAP estimate that stays physical where the data do not inform (noise, model
#: mismatch); the paper's Algorithm 2 has none (the default).
COIN_PRIOR = {"mass_kg": (1.37e-3, math.log(2.0)), "mu_b": (0.22, math.log(2.0)), "mu_t": (0.52, math.log(2.0))}
#: the named priors of ``deapull control --phi-prior`` (:func:`named_prior`)
PRIOR_NAMES = ("none", "coins", "family")


@functools.lru_cache(maxsize=None)
def design_coins(scene: str = "coin_pull") -> dict[str, Phi]:
    """The coins of the shipped scene's setups (C1..C8), as the FEM makes them: m_c = the coin's
    density × its cylinder's volume π r² h (the FEM's coin mesh has that volume), μ_b and μ_t."""
    coins = {}
    for setup in scenes.setups_of(scene):
        c = scenes.load(scene, setup=setup).coin
        coins[setup] = Phi(mass_kg=c.density_kg_m3 * math.pi * c.radius_m ** 2 * c.height_m, mu_b=c.mu_b,
                           mu_t=c.mu_t)
    return coins


def family_prior(scene: str = "coin_pull") -> dict:
    """The coin family's own spread as a log-normal prior (``--phi-prior family``): each field's
    median at the geometric middle of :func:`design_coins` (m_c 1.36–1.38 g, μ_b 0.20–0.25, μ_t
    0.50–0.55) and its log std half their log range, so that the family's extremes lie at ±1 std."""
    prior = {}
    for f in ("mass_kg", "mu_b", "mu_t"):
        values = [coin.value(f) for coin in design_coins(scene).values()]
        lo, hi = min(values), max(values)
        prior[f] = (math.sqrt(lo * hi), 0.5 * math.log(hi / lo))
    return prior


def named_prior(name: str) -> dict | None:
    """The prior of :data:`PRIOR_NAMES`: none (maximum likelihood), coins (:data:`COIN_PRIOR`) or
    family (:func:`family_prior`)."""
    if name not in PRIOR_NAMES:
        raise InputError(f"prior {name!r}: choose one of {', '.join(PRIOR_NAMES)}")
    if name == "family":
        return family_prior()
    return COIN_PRIOR if name == "coins" else None


#: what the online inference fits φ to (:attr:`InferenceConfig.loss`)
LOSSES = ("step", "rollout")


@dataclass(frozen=True)
class InferenceConfig:
    """Settings of the online inference.

    Attributes
    ----------
    fields : tuple of str or None
        The fields of φ to infer (None: every field the model uses). The others stay at their
        ``initial`` value, or at the prior's median where ``prior`` has one.
    initial : dict or None
        Starting value per field (SI units). None (the default): :data:`INITIAL`, except that a
        field of ``prior`` starts at the prior's median, the estimate before any data (from
        INITIAL's 0.001 g coin the rollout loss, at most ``max_log_step`` per update, needs ~15
        updates to reach a 1.4 g coin, and the MPC plans on the wrong coin meanwhile). The values
        used are :attr:`start`.
    lr : float
        Adam's learning rate on log φ.
    batch_size : int
        Transitions per update (paper: 256; fewer while the buffer holds fewer).
    updates_per_step : int
        Adam steps per control step.
    residual_scale_m : float
        s: the position residual's unit in the loss (m).
    capacity : int or None
        Most transitions kept (oldest dropped); None: all.
    seed : int
        Seeds the batch sampling.
    stick_hinge : bool
        Add the stick hinge to eq. 9 (:meth:`OnlineInference.loss`; tip-contact model).
    motion_threshold_m : float
        A transition whose observed position changes by more than this counts as moving
        (for the hinge); raise it to a few noise stds under observation noise.
    prior : dict or None
        A log-normal prior per field, ``{field: (median, std of log φ)}`` (e.g.
        :data:`COIN_PRIOR`); None: maximum likelihood (the paper). With a prior each update
        minimises eq. 9 plus ``w² Σ ((log φ − log median)/std)²``, ``w² = (n/N) σ̂²/s²``:
        the batch of n stands for the buffer's N transitions, and σ̂, the std of one
        transition's residual, is the larger of ``observation_std_m`` and the batch's RMS
        residual at the current φ (the model's misfit, estimated as in weighted least
        squares with unknown variance). So the prior weighs like one transition of the
        current misfit per field: it decides where the data do not (noise, stuck
        transitions, a model that cannot fit the plant) and hardly moves an estimate the
        data determine.
    observation_std_m : float
        The smallest σ̂ (m): the observation noise's std (the MPC passes the env's); the
        default 1 nm only keeps w > 0 on noise-free data.
    engine : {"auto", "native", "torch"}
        Where the Levenberg–Marquardt step evaluates the residuals and their Jacobian:
        ``native`` in C (:func:`deapull.control.native.coin_predict` for f-coulomb,
        :func:`~deapull.control.native.memory_predict` for f-memory, whose buffer's memory is
        then re-derived in C too (:func:`~deapull.control.native.memory_scan`); the same
        numbers to round-off), ``torch`` by autograd through the model, ``auto`` native
        where available. Adam always uses torch.
    loss : {"step", "rollout"}
        What the MPC fits φ to: ``step`` the paper's one-step predictions from the observed state
        (Algorithm 2, :class:`OnlineInference`); ``rollout`` f_a's open-loop rollout of the whole
        episode under the applied voltages against every observed position
        (:class:`~deapull.control.rollout_inference.RolloutInference`: no noise in its inputs; one
        Levenberg–Marquardt update every ``every`` steps).
    every : int
        Control steps between ``rollout`` updates.
    crlb_every : int
        The MPC reports the inferred fields' Cramér–Rao bounds every this many transitions (0:
        never; with a prior and the one-step loss they gate which fields it plans with).
    memory_refresh : int
        A model with memory (f-memory: the tip's contact point and friction before each
        transition, which depend on φ through the whole history): every this many updates
        the buffer's memory is re-derived along all its rows under the current estimate
        (between refreshes each new row starts from the previous row's step at the estimate
        of its time). Each update fits φ through one step per row with that memory given.
    """

    fields: tuple | None = None
    initial: dict | None = None
    lr: float = 0.05
    batch_size: int = 256
    updates_per_step: int = 1
    residual_scale_m: float = 1e-6
    capacity: int | None = None
    seed: int = 0
    stick_hinge: bool = True
    motion_threshold_m: float = 1e-9
    optimizer: str = "adam"
    damping: float = 1e-3
    max_log_step: float = 0.5
    wait_for_motion: bool = True
    prior: dict | None = None
    observation_std_m: float = 1e-9
    engine: str = "auto"
    memory_refresh: int = 1
    loss: str = "step"
    every: int = 10
    crlb_every: int = 100

    @property
    def start(self) -> dict:
        """The starting value of every field (SI units): ``initial``, or its default; a field left out of
        ``fields`` is held at the prior's median (what a plan uses for it)."""
        prior = self.prior or {}
        held = {f: m for f, (m, _) in prior.items() if self.initial is None or (self.fields is not None
                                                                               and f not in self.fields)}
        return {**(INITIAL if self.initial is None else self.initial), **held}

    def __post_init__(self):
        if not self.lr > 0 or self.batch_size < 1 or self.updates_per_step < 0 or not self.residual_scale_m > 0:
            raise InputError(f"inference settings out of range: lr {self.lr} > 0, batch_size {self.batch_size} >= 1, "
                             f"updates_per_step {self.updates_per_step} >= 0, residual_scale_m "
                             f"{self.residual_scale_m} > 0")
        if self.optimizer not in OPTIMIZERS:
            raise InputError(f"inference optimizer {self.optimizer!r}: choose one of {', '.join(OPTIMIZERS)}")
        if self.engine not in ENGINES:
            raise InputError(f"inference engine {self.engine!r}: choose one of {', '.join(ENGINES)}")
        if self.loss not in LOSSES:
            raise InputError(f"mpc.inference.loss = {self.loss!r}: choose one of {', '.join(LOSSES)}")
        if self.loss == "rollout" and self.optimizer != "lm":
            raise InputError(f"mpc.inference.loss = 'rollout' takes Levenberg-Marquardt steps: "
                             f"mpc.inference.optimizer = 'lm', not {self.optimizer!r}")
        for name in ("every", "crlb_every"):
            value = getattr(self, name)
            if int(value) != value or value < (1 if name == "every" else 0):
                raise InputError(f"mpc.inference.{name} = {value!r}: must be an integer >= "
                                 f"{1 if name == 'every' else 0} (control steps)")
        for f, spec in (self.prior or {}).items():
            if f not in BOUNDS:
                raise InputError(f"inference prior: unknown field {f!r}; choose from {', '.join(BOUNDS)}")
            if len(spec) != 2 or not spec[0] > 0 or not spec[1] > 0:
                raise InputError(f"inference prior of {f!r}: {spec!r}; expected (median > 0, std of log > 0)")
        if not self.observation_std_m > 0:
            raise InputError(f"inference observation_std_m {self.observation_std_m} must be > 0")
        if self.memory_refresh < 1:
            raise InputError(f"inference memory_refresh {self.memory_refresh} must be at least 1 (updates)")
        if self.capacity is not None and self.capacity < 1:
            raise InputError(f"inference capacity {self.capacity} must be at least 1 (or None)")


class Predictor:
    """x̂_{t+1}(φ) of buffered transitions for one model, θ fixed: what the model kind offers
    under its ``infer`` capability.

    ``cache(x_prev, x, V, V_next, dt)`` evaluates what does not depend on φ once (float64
    columns); ``predict(columns, phi)`` gives the next positions, differentiable in φ.
    """

    def __init__(self, model):
        if "infer" not in capabilities(model):
            raise InputError(f"online inference needs a model that can infer φ (capability 'infer'); "
                             f"{model.kind!r} offers {sorted(capabilities(model)) or 'nothing'}")
        self.model = model
        self.adapter = adapter(model)

    @property
    def memory(self) -> bool:
        """Whether the model's step needs memory entries (:attr:`~deapull.control.adapters.Adapter.plan_memory`)
        that the buffer carries along its rows."""
        return bool(self.adapter.plan_memory)

    def cache(self, x_prev, x, V, V_next, dt, memory=None) -> dict:
        if self.memory:
            return self.adapter.inference_columns(x_prev, x, V, V_next, dt, memory)
        return self.adapter.inference_columns(x_prev, x, V, V_next, dt)

    def memory_after(self, c: dict, phi: Phi) -> torch.Tensor:
        """Memory kinds: the entries after each row's transition."""
        return self.adapter.memory_after(c, phi)

    def memory_along(self, c: dict, phi: Phi) -> torch.Tensor:
        """Memory kinds: the entries before each of consecutive rows, re-derived from the first."""
        return self.adapter.memory_along(c, phi)

    def predict(self, c: dict, phi: Phi) -> torch.Tensor:
        """x̂_{t+1} of the cached rows ``c`` for the coin ``phi``."""
        return self.adapter.predict_columns(c, phi)

    def stick_shortfall(self, c: dict, phi: Phi) -> torch.Tensor | None:
        """How far (m/s) a row the model holds stuck is from slipping (None for a kind without
        a stick state)."""
        return self.adapter.stick_shortfall(c, phi)

    def predict_with_shortfall(self, c: dict, phi: Phi, shortfall: bool):
        """(:meth:`predict`, :meth:`stick_shortfall` if ``shortfall`` else None) in one go."""
        return self.adapter.predict_with_shortfall(c, phi, shortfall)


class ReplayBuffer:
    """Observed transitions, with the φ-free parts of their prediction cached."""

    def __init__(self, predictor: Predictor, capacity: int | None = None):
        self.predictor, self.capacity = predictor, capacity
        self.columns: dict = {}
        self.target = torch.zeros(0, dtype=torch.float64)

    def __len__(self) -> int:
        return self.target.shape[0]

    def add(self, x_prev: float, x: float, x_next: float, V: float, V_next: float, dt: float,
            memory: torch.Tensor | None = None) -> None:
        """One transition: positions x̃_{t−1}, x̃_t, x̃_{t+1} (m), voltages V_t, V_{t+1} (V) and,
        for a model with memory, its entries before the transition ((1, k); None: at rest)."""
        row = torch.tensor([[x_prev, x, V, V_next, dt]], dtype=torch.float64)
        new = self.predictor.cache(*row.unbind(-1), memory=memory)
        self.columns = new if not self.columns else {k: torch.cat([self.columns[k], new[k]]) for k in new}
        self.target = torch.cat([self.target, torch.tensor([x_next], dtype=torch.float64)])
        if self.capacity is not None and len(self) > self.capacity:
            self.columns = {k: v[-self.capacity:] for k, v in self.columns.items()}
            self.target = self.target[-self.capacity:]

    def batch(self, index: torch.Tensor) -> tuple[dict, torch.Tensor]:
        return {k: v[index] for k, v in self.columns.items()}, self.target[index]


class OnlineInference:
    """Algorithm 2's inference: a replay buffer and Adam on log φ.

    Parameters
    ----------
    model : Surrogate
        f_a (a kind with the ``infer`` capability: ``f-coulomb``, ``f-memory`` or ``f``); a
        float64 copy is used, its weights frozen.
    config : InferenceConfig
    dt : float
        The control step Δt (s).

    Use: ``reset()`` at the start of an episode, then per step ``observe(x̃_t, V_t)`` and
    ``update()``; :attr:`phi` is the current estimate and :attr:`log` holds one record per
    update (iteration, loss, buffer size, every field).
    """

    def __init__(self, model, config: InferenceConfig = InferenceConfig(), dt: float = 1e-3):
        self.model = copy.deepcopy(model).double().eval().requires_grad_(False)
        self.config, self.dt = config, float(dt)
        self.fields = tuple(config.fields) if config.fields is not None else tuple(model.phi_fields)
        unknown = [f for f in self.fields if f not in model.phi_fields]
        if unknown:
            raise InputError(f"cannot infer {', '.join(unknown)}: the {model.kind} model uses "
                             f"{', '.join(model.phi_fields)}")
        missing = [f for f in model.phi_fields if f not in config.start]
        if missing:
            raise InputError(f"no initial value for {', '.join(missing)} (InferenceConfig.initial)")
        self.predictor = Predictor(self.model)
        self.native = native.predictor(capabilities(model)) if config.engine != "torch" else None
        if config.engine == "native" and self.native is None:
            raise InputError(f"the native inference needs a model with the 'compiled_mpc' or 'compiled_mpc_memory' "
                             f"capability and a C compiler (model: {model.kind!r})")
        self.reset()

    def reset(self) -> None:
        """Back to the initial φ with an empty buffer (a new episode)."""
        cfg = self.config
        self.log_phi = {f: torch.tensor(math.log(cfg.start[f]), dtype=torch.float64, requires_grad=True)
                        for f in self.fields}
        self.optimizer = torch.optim.Adam(list(self.log_phi.values()), lr=cfg.lr)
        self.damping = cfg.damping
        self.buffer = ReplayBuffer(self.predictor, cfg.capacity)
        self.generator = torch.Generator().manual_seed(cfg.seed)
        self.history: list = []          # (x̃, V) observed so far
        self.tip = None                  # a memory model's entries before the next transition (None: at rest)
        self.log: list = []
        self.iteration = 0
        self.moved = False

    def _phi(self, detach: bool) -> Phi:
        values = {}
        for f in self.model.phi_fields:
            if f in self.log_phi:
                v = self.log_phi[f].exp()
                values[f] = v.detach() if detach else v
            else:
                values[f] = torch.tensor(float(self.config.start[f]), dtype=torch.float64)
        return Phi(**values)

    @property
    def transitions(self) -> int:
        """Transitions in the buffer."""
        return len(self.buffer)

    @property
    def phi(self) -> Phi:
        """The current estimate (float64 0-d tensors, no gradient)."""
        return self._phi(detach=True)

    def estimate(self) -> dict:
        """The current estimate by field (floats, SI units)."""
        return {f: float(self.log_phi[f].detach().exp()) if f in self.log_phi else float(self.config.start[f])
                for f in self.model.phi_fields}

    def observe(self, x_m: float, V_V: float) -> None:
        """Record the observed position x̃_t (m) and the voltage V_t (V) of step t; from the
        second observation on, the transition into it joins the buffer."""
        self.history.append((float(x_m), float(V_V)))
        if len(self.history) >= 2:
            (x1, V1), (x2, V2) = self.history[-2], self.history[-1]
            x0 = self.history[-3][0] if len(self.history) >= 3 else x1   # u_0 = 0: at rest
            self.buffer.add(x0, x1, x2, V1, V2, self.dt, self.tip)
            if self.predictor.memory:      # where the tip goes in that transition, at today's estimate
                last = {k: v[-1:] for k, v in self.buffer.columns.items()}
                self.tip = self._memory_after(last)
        del self.history[:-3]

    def refresh_memory(self) -> None:
        """A memory model's entries along the whole buffer re-derived at the current estimate
        (:attr:`InferenceConfig.memory_refresh`); the next transition starts from the last."""
        if not self.predictor.memory or not len(self.buffer):
            return
        columns, phi = self.buffer.columns, self.phi
        if self.native is not None:     # the scan in C: the memory after every row at once
            after = native.memory_scan(self.model, columns, self.estimate())
            columns["memory"] = torch.cat([columns["memory"][:1], after[:-1]])
            self.tip = after[-1:]
            return
        columns["memory"] = self.predictor.memory_along(columns, phi)
        self.tip = self.predictor.memory_after({k: v[-1:] for k, v in columns.items()}, phi)

    def _memory_after(self, rows: dict) -> torch.Tensor:
        """A memory model's entries after the step of ``rows`` (one row), at the estimate."""
        if self.native is not None:
            return native.memory_scan(self.model, rows, self.estimate())
        return self.predictor.memory_after(rows, self.phi)

    def residuals(self, columns: dict, target: torch.Tensor, phi: Phi) -> torch.Tensor:
        """The residuals whose mean square is the loss: eq. 9's position errors in units of
        ``residual_scale_m``, then (tip-contact model, ``stick_hinge``) the stick hinge.

        Where the model holds the coin stuck, its prediction does not depend on φ at all
        (zero gradient), so eq. 9 alone can never leave a φ that holds the coin stuck while
        it is seen to move. For transitions observed to move (|x̃_{t+1} − x̃_t| >
        ``motion_threshold_m``) that the model holds stuck, the hinge adds the displacement
        the missing slip margin stands for (:meth:`Predictor.stick_shortfall` · Δt, same
        units); it is zero wherever the model lets the coin slip.
        """
        cfg = self.config
        pred, shortfall = self.predictor.predict_with_shortfall(columns, phi, cfg.stick_hinge)
        r = (pred - target) / cfg.residual_scale_m
        if shortfall is None:
            return r
        moving = ((target - columns["s"][..., 0]).abs() > cfg.motion_threshold_m).double()
        return torch.cat([r, moving * shortfall * columns["a"][..., 1] / cfg.residual_scale_m])

    def loss(self, columns: dict, target: torch.Tensor, phi: Phi) -> torch.Tensor:
        """Mean square of :meth:`residuals` (per transition)."""
        return (self.residuals(columns, target, phi) ** 2).sum() / target.shape[0]

    def _phi_rows(self, log_values: torch.Tensor) -> Phi:
        """φ with the inferred fields from per-row log values (n, p), the rest fixed."""
        values = {f: torch.tensor(float(self.config.start[f]), dtype=torch.float64) for f in self.model.phi_fields}
        values.update({f: log_values[:, i].exp() for i, f in enumerate(self.fields)})
        return Phi(**values)

    def _sample(self):
        n = len(self.buffer)
        size = min(self.config.batch_size, n)
        index = torch.randint(n, (size,), generator=self.generator) if n > size else torch.arange(n)
        return self.buffer.batch(index)

    def _prior_weight(self, data_residuals: torch.Tensor) -> float:
        """w of the prior term (``InferenceConfig.prior``), from the batch's residuals at the
        current φ (in units of ``residual_scale_m``); held fixed through one update."""
        cfg = self.config
        n, N = data_residuals.shape[0], max(len(self.buffer), 1)
        rms = float(data_residuals.detach().pow(2).mean().sqrt()) if n else 0.0
        return math.sqrt(n / N) * max(cfg.observation_std_m / cfg.residual_scale_m, rms)

    def _prior_rows(self, log_values: torch.Tensor, weight: float) -> tuple[torch.Tensor, torch.Tensor]:
        """The prior's residuals w (log φ − log median)/std of the inferred fields that have
        a prior, and their Jacobian with respect to ``log_values`` (rows × p)."""
        prior, p = self.config.prior or {}, len(self.fields)
        index = [i for i, f in enumerate(self.fields) if f in prior]
        centre = torch.tensor([math.log(prior[self.fields[i]][0]) for i in index], dtype=torch.float64)
        std = torch.tensor([prior[self.fields[i]][1] for i in index], dtype=torch.float64)
        r = weight * (log_values[index] - centre) / std
        J = torch.zeros(len(index), p, dtype=torch.float64)
        J[range(len(index)), index] = weight / std
        return r, J

    def _adam_step(self, columns, target) -> float:
        self.optimizer.zero_grad()
        loss = self.loss(columns, target, self._phi(detach=False))
        if self.config.prior:
            with torch.no_grad():
                data = (self.predictor.predict(columns, self.phi) - target) / self.config.residual_scale_m
            log_values = torch.stack([self.log_phi[f] for f in self.fields])
            loss = loss + (self._prior_rows(log_values, self._prior_weight(data))[0] ** 2).sum() / target.shape[0]
        loss.backward()
        self.optimizer.step()
        with torch.no_grad():
            for i, f in enumerate(self.fields):
                self.log_phi[f].copy_(self._clamp(self.log_phi[f].detach().reshape(1), i)[0])
        return float(loss.detach())

    def _clamp(self, log_values: torch.Tensor, first: int = 0) -> torch.Tensor:
        """log φ kept inside :data:`BOUNDS` (fields from ``first`` on)."""
        lo = torch.tensor([math.log(BOUNDS[f][0]) for f in self.fields[first:first + len(log_values)]],
                          dtype=torch.float64)
        hi = torch.tensor([math.log(BOUNDS[f][1]) for f in self.fields[first:first + len(log_values)]],
                          dtype=torch.float64)
        return torch.minimum(torch.maximum(log_values, lo), hi)

    def _lm_step(self, columns, target) -> float:
        """One Levenberg–Marquardt step on log φ over the batch: the residuals' Jacobian
        (n_r × p) from per-row copies of log φ (rows are independent), the damped
        Gauss–Newton step, kept if the batch loss falls (damping ÷3), else damping ×4."""
        n, p = target.shape[0], len(self.fields)
        current = torch.stack([self.log_phi[f].detach() for f in self.fields])
        if self.native is not None:
            r, J = self._native_residuals(columns, target, current, jacobian=True)
        else:
            rows = current.expand(n, p).clone().requires_grad_(True)
            with torch.enable_grad():
                r = self.residuals(columns, target, self._phi_rows(rows))
                # each residual depends on its own row of ``rows``: the row-sums of blocks of n
                J = torch.cat([torch.autograd.grad(block.sum(), rows, retain_graph=True)[0]
                               for block in r.split(n)])
            r = r.detach()
        prior_loss = None
        if self.config.prior:
            weight = self._prior_weight(r[:n])
            rp, Jp = self._prior_rows(current, weight)
            r, J = torch.cat([r, rp]), torch.cat([J, Jp])
            prior_loss = lambda values: float((self._prior_rows(values, weight)[0] ** 2).sum()) / n  # noqa: E731
        loss = float((r ** 2).sum()) / n
        H, g = J.T @ J, J.T @ r
        scale = torch.diag(torch.diagonal(H)) + 1e-12 * torch.eye(p, dtype=H.dtype)
        for _ in range(30):
            step = -torch.linalg.solve(H + self.damping * scale, g)
            step = step * torch.clamp(self.config.max_log_step / step.abs().max().clamp(min=1e-300), max=1.0)
            trial = self._clamp(current + step)
            if not torch.isfinite(trial).all():
                new = math.inf
            elif self.native is not None:
                new = float((self._native_residuals(columns, target, trial, jacobian=False)[0] ** 2).sum()) / n
            else:
                new = float(self.loss(columns, target, self._phi_rows(trial.expand(n, p))))
            if prior_loss is not None:
                new += prior_loss(trial)
            if new < loss:
                self.damping = max(self.damping / 3, 1e-9)
                with torch.no_grad():
                    for f, v in zip(self.fields, trial):
                        self.log_phi[f].copy_(v)
                return new
            self.damping = min(self.damping * 4, 1e12)
            if self.damping >= 1e12:
                break
        return loss

    def _native_residuals(self, columns, target, log_values: torch.Tensor, jacobian: bool):
        """:meth:`residuals` at one φ (inferred fields from ``log_values``) and their
        Jacobian with respect to those log values, evaluated in C."""
        cfg = self.config
        values = {f: float(cfg.start[f]) for f in self.model.phi_fields}
        values.update({f: math.exp(float(v)) for f, v in zip(self.fields, log_values)})
        pred, dpred, short, dshort = self.native(self.model, columns, values, jacobian)
        columns_of = [("mass_kg", "mu_b", "mu_t").index(f) for f in self.fields]
        r = (pred - target) / cfg.residual_scale_m
        J = dpred[:, columns_of] / cfg.residual_scale_m if jacobian else None
        if cfg.stick_hinge:
            moving = ((target - columns["s"][..., 0]).abs() > cfg.motion_threshold_m).double()
            weight = moving * columns["a"][..., 1] / cfg.residual_scale_m
            r = torch.cat([r, weight * short])
            if jacobian:
                J = torch.cat([J, weight[:, None] * dshort[:, columns_of]])
        return r, J

    def misfit_m(self) -> float:
        """RMS position residual (m) of the one-step predictions over the buffer at the current φ."""
        columns, target = self.buffer.batch(torch.arange(len(self.buffer)))
        if not len(target):
            return 0.0
        return float((self.predictor.predict(columns, self.phi) - target).pow(2).mean().sqrt())

    def sensitivity(self) -> torch.Tensor:
        """∂x̂_{t+1}/∂log φ (N × p) of the buffered one-step predictions at the current estimate."""
        with torch.enable_grad():
            return _sensitivity(self, self.phi)[0].detach()

    def crlb(self, noise_std_m: float) -> dict:
        """Each inferred field's Cramér–Rao bound on its relative error (:func:`identifiability`)."""
        with torch.enable_grad():
            return identifiability(self, noise_std_m=noise_std_m)["crlb_relative"]

    def update(self, steps: int | None = None) -> dict | None:
        """``steps`` (default ``updates_per_step``) updates of log φ on a random batch each;
        returns the last log record (None while the buffer is empty)."""
        record = None
        if self.config.wait_for_motion and not self.moved:
            self.moved = bool(len(self.buffer)) and bool(
                ((self.buffer.target - self.buffer.columns["s"][:, 0]).abs() > self.config.motion_threshold_m).any())
            if not self.moved:
                return record
        for _ in range(self.config.updates_per_step if steps is None else steps):
            if len(self.buffer) == 0:
                return record
            columns, target = self._sample()
            step = self._lm_step if self.config.optimizer == "lm" else self._adam_step
            loss = step(columns, target)
            self.iteration += 1
            if self.predictor.memory and self.iteration % self.config.memory_refresh == 0:
                self.refresh_memory()
            record = {"iteration": self.iteration, "loss": loss, "transitions": len(self.buffer), **self.estimate()}
            self.log.append(record)
            log.debug("inference %d: loss %.3g, %s", self.iteration, loss, self.estimate())
        return record


def posterior(inference, noise_std_m: float, level: float = 0.68, profile: bool = True) -> dict:
    """The posterior of the inferred fields at the current estimate of ``inference``
    (:class:`OnlineInference`, or the output-error
    :class:`~deapull.control.rollout_inference.RolloutInference`): its Laplace approximation, and for
    the output-error inference its profile-likelihood interval.

    In log φ the posterior's covariance is (SᵀS/σ̂² + P)⁻¹: S = ∂x̂/∂log φ over everything
    observed (one-step predictions, or the episode's rollout), σ̂ the larger of ``noise_std_m``
    and the RMS misfit at the estimate (the model's own error counts as noise, as in the MAP's
    weighting), P the prior's precision (diag 1/std², 0 for a field without one). Returns, per
    field, the ``estimate``, ``std_log`` (the posterior std of log φ) and the central ``level``
    interval (``lo``, ``hi``: estimate × exp(∓ z std_log), z the normal quantile); a field that
    neither the data nor the prior determine gets std_log = inf.

    With ``profile`` (the default) and the output-error inference, ``lo`` and ``hi`` are instead its
    profile-likelihood interval (:meth:`RolloutInference.profile_interval`), and ``method`` says which:
    the push's data leave a curved ridge along μ_b and μ_t together, across which the Laplace
    interval is too narrow (at 1 µm it covered 57 % of 96 coins drawn from the family prior, with
    estimates up to 7 of its stds off; bench/bench_inference.py).
    """
    fields = tuple(inference.fields)
    sigma = max(noise_std_m, inference.misfit_m())
    S = np.asarray(inference.sensitivity(), dtype=np.float64)
    precision = S.T @ S / sigma ** 2
    prior = inference.config.prior or {}
    for i, f in enumerate(fields):
        if f in prior:
            precision[i, i] += 1.0 / prior[f][1] ** 2
    try:
        std = np.sqrt(np.clip(np.diag(np.linalg.inv(precision)), 0, None)).tolist()
    except np.linalg.LinAlgError:
        std = [math.inf] * len(fields)
    z = statistics.NormalDist().inv_cdf(0.5 + level / 2)
    estimate = inference.estimate()
    out = {f: {"estimate": estimate[f], "std_log": sd, "lo": estimate[f] * math.exp(-z * sd),
               "hi": estimate[f] * math.exp(z * sd), "method": "laplace"} for f, sd in zip(fields, std)}
    if profile and hasattr(inference, "profile_interval"):
        for f in fields:
            out[f]["lo"], out[f]["hi"] = inference.profile_interval(f, noise_std_m, level)
            out[f]["method"] = "profile"
    return out


def _sensitivity(inference: OnlineInference, base: Phi):
    """(S, x̂_{t+1}, columns): ∂x̂_{t+1}/∂log φ (N × p) over the buffer at ``base``."""
    fields = inference.fields
    columns, _ = inference.buffer.batch(torch.arange(len(inference.buffer)))
    n = len(inference.buffer)
    logs = {f: torch.log(torch.full((n,), base.value(f), dtype=torch.float64)).requires_grad_(True) for f in fields}
    values = {f: (logs[f].exp() if f in logs else getattr(base, f)) for f in FIELDS if getattr(base, f) is not None}
    x_next = inference.predictor.predict(columns, Phi(**values))
    grads = torch.autograd.grad(x_next.sum(), [logs[f] for f in fields])
    return torch.stack(grads, -1), x_next, columns


def identifiability(inference: OnlineInference, phi: Phi | None = None, noise_std_m: float = 1e-6) -> dict:
    """What the buffered transitions say about each inferred field, at ``phi`` (default: the
    current estimate).

    For the N buffered transitions, S = ∂x̂_{t+1}/∂log φ (N × p) is the sensitivity of the
    predicted positions to a relative change of each parameter. With Gaussian position
    noise σ the Fisher information is F = SᵀS/σ², and the Cramér–Rao bound on the relative
    error of each parameter (all inferred together) is √(F⁻¹)_ii.

    Returns
    -------
    dict
        ``fields``; ``sensitivity_m`` (RMS over transitions of ∂x̂/∂log φ_i, m: a 10 %
        change moves the prediction by ~0.1× that per step); ``moving_fraction`` (of
        transitions whose predicted position changes); ``fisher`` (p × p list);
        ``eigenvalues`` of F; ``crlb_relative`` per field (inf where F is singular);
        ``noise_std_m``, ``transitions``.
    """
    fields = inference.fields
    base = inference.phi if phi is None else phi.to(dtype=torch.float64)
    S, x_next, columns = _sensitivity(inference, base)
    n = S.shape[0]
    F = S.T @ S / noise_std_m ** 2
    eig = torch.linalg.eigvalsh(F)
    try:
        crlb = torch.sqrt(torch.clamp(torch.diagonal(torch.linalg.inv(F)), min=0)).tolist()
    except torch.linalg.LinAlgError:
        crlb = [math.inf] * len(fields)
    if not eig.min() > 1e-12 * max(float(eig.max()), 1e-300):
        crlb = [math.inf] * len(fields)
    moving = (columns["s"][:, 1].abs() > 0) | ((x_next - columns["s"][:, 0]).abs() > 0)
    return {"fields": list(fields), "transitions": n, "noise_std_m": noise_std_m,
            "sensitivity_m": dict(zip(fields, S.pow(2).mean(0).sqrt().tolist())),
            "moving_fraction": float(moving.double().mean()) if n else 0.0,
            "fisher": F.tolist(), "eigenvalues": eig.tolist(), "crlb_relative": dict(zip(fields, crlb))}
