"""The MPC policy on f_a (paper Algorithm 2, MPC branch); f_a's scaled dynamics and cost are in
:mod:`deapull.control.dynamics`.

**Dead zone and reach.** Below the onset voltage the model holds the coin stuck and every
Jacobian of x with respect to the controls is 0, so iLQR cannot see that more voltage
helps; and when the onset lies near the end of the horizon, the little motion the plan
sees there is not worth its ΔV penalty, so iLQR settles on ΔV = 0 and the coin never
starts (we measured exactly that). Each step the policy therefore rolls the model out
under the full ramp (ν = 1 over the horizon). While the coin is short of the target and
even the ramp does not bring it within the tolerance of the target inside the horizon,
the policy applies the ramp without solving: voltage moves the coin one way only while
it advances, so the ramp keeps the coin furthest along at every step, which is what the
position cost asks for; the ΔV penalty alone would argue for less. Once the target is
within the horizon's reach, the policy solves from two warm starts at once (a batch of two
rows): the previous plan shifted by one step and the ramp, and applies the first control
of the cheaper plan.

**Velocity.** The env observes x (noisy) and V, not u. Without noise u_t = (x_t − x_{t−1})/Δt
(exact for the backward-Euler step of f); with noise, the model's own prediction of u_t
from the previous estimate and the applied voltages. The position is the observation
itself, or with ``filter="kf"`` (policy ``mpc+kf``) the estimate of a Kalman filter whose
prediction is that same model step (:mod:`deapull.control.filters`).
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass, field, replace

import torch

from deapull.control import mpc, native
from deapull.control.dynamics import COSTS, U_UNIT_M_S, V_UNIT_V, X_UNIT_M, CoinDynamics, coin_cost
from deapull.control.filters import FILTERS, ModelKalman
from deapull.control.inference import InferenceConfig, OnlineInference
from deapull.control.policies import Policy
from deapull.errors import InputError
from deapull.surrogate.phi import Phi

ENGINES = ("auto", "native", "torch")


def make_dynamics(model, phi: Phi, dt: float, dv_max_V: float, v_max_V: float, engine: str = "auto"):
    """f_a as :class:`CoinDynamics` (``engine="torch"``) or its compiled twin
    :class:`~deapull.control.native.NativeCoinDynamics` (``"native"``; ``"auto"``: where
    available)."""
    if engine == "native" or (engine == "auto" and native.available(model)):
        if not native.available(model):
            raise InputError(f"the native MPC needs an f-coulomb f_a and a C compiler (f_a is {model.kind!r}; "
                             f"compiler {'found' if native.library() is not None else 'missing'})")
        return native.NativeCoinDynamics(model, phi, dt, dv_max_V, v_max_V)
    return CoinDynamics(model, phi, dt, dv_max_V, v_max_V)


@dataclass(frozen=True)
class MPCConfig:
    """Settings of the MPC policy.

    Attributes
    ----------
    horizon, iterations : int
        Steps planned ahead and iLQR iterations per control step (paper: 20, 20).
    cost : {"scaled", "paper"}
    dv_weight : float
        w of the scaled cost.
    terminal_weight : float
        Weight of the final position term relative to a stage's.
    infer : bool
        Infer φ online (Algorithm 2) and plan with the current estimate; otherwise plan with
        the φ given to the policy.
    inference : InferenceConfig
    engine : {"auto", "native", "torch"}
        Where f_a's steps, Jacobians and the iLQR run: ``native`` the compiled solver of
        :mod:`deapull.control.native` (f-coulomb only; the same plans to round-off, ~1,000×
        faster), ``torch`` :func:`mpc.solve` on :class:`CoinDynamics`, ``auto`` native
        where it is available.
    filter : {"none", "kf"}
        ``kf``: plan from the estimate of a Kalman filter on the position whose prediction
        is f_a itself (:class:`~deapull.control.filters.ModelKalman`, process noise
        ``process_std_m`` per step at rest, plus ``process_fraction`` of each predicted
        step); the policy is then named ``mpc+kf``.
    process_std_m, process_fraction : float
    """

    horizon: int = 20
    iterations: int = 20
    cost: str = "scaled"
    dv_weight: float = 1e-3
    terminal_weight: float = 1.0
    infer: bool = True
    inference: InferenceConfig = field(default_factory=lambda: InferenceConfig(optimizer="lm"))
    engine: str = "auto"
    filter: str = "none"
    process_std_m: float = 1e-6
    process_fraction: float = 0.2

    def __post_init__(self):
        if self.filter not in FILTERS:
            raise InputError(f"MPC filter {self.filter!r}: choose one of {', '.join(FILTERS)}")
        if self.engine not in ENGINES:
            raise InputError(f"MPC engine {self.engine!r}: choose one of {', '.join(ENGINES)}")
        if self.horizon < 1 or self.iterations < 0:
            raise InputError(f"MPC horizon {self.horizon} must be >= 1 and iterations {self.iterations} >= 0")
        if self.cost not in COSTS:
            raise InputError(f"MPC cost {self.cost!r}: choose one of {', '.join(COSTS)}")


class MPCPolicy(Policy):
    """Model-predictive control on f_a with the inferred φ (paper Algorithm 2, MPC branch).

    Parameters
    ----------
    model : Surrogate
        f_a (``f-coulomb`` or ``f``), e.g. trained on C3..C8.
    config : MPCConfig
    phi : Phi, optional
        The coin to plan for when ``config.infer`` is False (e.g. the true one, for an
        oracle run); with inference on, ignored.

    Attributes
    ----------
    solve_ms : list of float
        Wall time of each step's MPC (plan only; inference not included), ms.
    inference_ms : list of float
        Wall time of each step's inference update, ms.
    """

    name = "mpc"

    def __init__(self, model, config: MPCConfig = MPCConfig(), phi: Phi | None = None):
        self.model, self.config = model, config
        self.name = "mpc" if config.filter == "none" else f"mpc+{config.filter}"
        if not config.infer and phi is None:
            raise InputError("an MPC without inference needs the φ to plan with")
        self.fixed_phi = None if phi is None else model.check_phi(phi).to(dtype=torch.float64)
        self.inference = None
        self.spec = None

    def reset(self, spec) -> None:
        cfg = self.config
        self.spec, self.target_m, self.tolerance_m = spec, float(spec.target_m), float(spec.tolerance_m)
        self.dt, self.dv_max_V, self.v_max_V = float(spec.dt_s), float(spec.dv_max_V), float(spec.v_max_V)
        noise = float(spec.noise_std_m)
        self.noisy = noise > 0
        self.kalman = None
        if cfg.filter == "kf":
            self.kalman = ModelKalman(noise, cfg.process_std_m, cfg.process_fraction)
        if cfg.infer:
            # a transition counts as moving (stick hinge) only beyond 3 noise stds
            # and the prior's smallest residual std is the noise's
            settings = replace(cfg.inference, motion_threshold_m=max(cfg.inference.motion_threshold_m, 3 * noise),
                               observation_std_m=max(cfg.inference.observation_std_m, noise))
            if self.inference is None or self.inference.dt != self.dt or self.inference.config != settings:
                self.inference = OnlineInference(self.model, settings, self.dt)
            self.inference.reset()
        phi = self.inference.phi if cfg.infer else self.fixed_phi
        self.dynamics = make_dynamics(self.model, phi, self.dt, self.dv_max_V, self.v_max_V, cfg.engine)
        self.native = callable(getattr(self.dynamics, "solve", None))
        self.cost = coin_cost(self.target_m, cfg.cost, cfg.dv_weight, cfg.terminal_weight)
        self.plan = None
        self.previous = None          # (x, u, V) estimate of the previous step
        self.solve_ms, self.inference_ms = [], []

    def inferred(self) -> dict:
        return self.inference.estimate() if self.inference is not None else {}

    def _estimate(self, x: float, V: float) -> tuple[float, float]:
        """(x, u) to plan from, given the observed x and the applied V (module docstring)."""
        if self.previous is None:
            return (x if self.kalman is None else self.kalman.reset(x)), 0.0
        x0, u0, V0 = self.previous
        if not self.noisy:
            return x, (x - x0) / self.dt
        with torch.no_grad():
            pred = self.dynamics(self.dynamics.state(x0, u0, V0),
                                 torch.tensor([[(V - V0) / self.dv_max_V]], dtype=torch.float64))[0]
        u = float(pred[1]) * U_UNIT_M_S
        if self.kalman is not None:
            x = self.kalman.update(float(pred[0]) * X_UNIT_M, x)
        return x, u

    @torch.no_grad()
    def act(self, obs, info) -> float:
        cfg = self.config
        x, V = self.spec.position_of(obs), float(info["V_V"])
        if cfg.infer:
            start = time.perf_counter()
            self.inference.observe(x, V)
            self.inference.update()
            self.dynamics.phi = self.inference.phi
            self.inference_ms.append(1e3 * (time.perf_counter() - start))
        start = time.perf_counter()
        x, u = self._estimate(x, V)
        self.previous = (x, u, V)
        xi0 = self.dynamics.state(x, u, V)
        T = cfg.horizon
        ramp = torch.ones(1, T, 1, dtype=torch.float64)
        out_of_reach = False
        if x - self.target_m > self.tolerance_m:
            roll = self.dynamics.rollout if self.native else functools.partial(mpc.rollout, self.dynamics)
            reach = roll(xi0, ramp)[0, :, 0] * X_UNIT_M
            out_of_reach = bool(reach.min() > self.target_m + self.tolerance_m)
        if out_of_reach:
            self.plan = ramp
        else:
            warm = mpc.shift(self.plan) if self.plan is not None else ramp
            solver = self.dynamics.solve if self.native else functools.partial(mpc.solve, self.dynamics)
            sol = solver(self.cost, xi0.repeat(2, 1), torch.cat([warm, ramp]), -1.0, 1.0, iterations=cfg.iterations)
            self.plan = sol.u[int(sol.cost.argmin())].unsqueeze(0)
        self.solve_ms.append(1e3 * (time.perf_counter() - start))
        return float(self.plan[0, 0, 0]) * self.dv_max_V
