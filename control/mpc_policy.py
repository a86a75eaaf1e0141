"""The MPC policy on f_a (paper Algorithm 2, MPC branch); f_a's scaled dynamics and cost are in
:mod:`deapull.control.dynamics`.

**Dead zone and reach.** Below the onset voltage the model holds the coin stuck and every
Jacobian of x with respect to the controls is 0, so iLQR cannot see that more voltage
helps; and when the onset lies near the end of the horizon, the little motion the plan
sees there is not worth its ΔV penalty, so iLQR settles on ΔV = 0 and the coin never
starts. Each step the policy therefore rolls the model out
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

**Offset-free tracking** (``estimator.kind = "bias"``, the default, at every noise level). f_a is
a model of other coins (C3..C7) and of the surrogate's data, not of the plant: on the FEM
its travel per volt is off by a roughly constant factor while the coin slides, and an MPC
that trusts it overshoots or stops short. A :class:`~deapull.control.filters.BiasKalman`
estimates that factor, g, with the position (x' = x + (1 + g) Δ, Δ the model's step), and
the plan aims the model at x̂ + (x^T − x̂)/(1 + g): the model's travel that the plant turns
into the remaining distance. Once the estimate is inside ``HOLD_BAND`` × tolerance of the
target the policy holds V (ΔV = 0) until the estimate leaves that band by more than its
own standard deviation: at constant V static friction holds the coin, so holding is
what settles it, and the MPC's own small corrections on a noisy estimate are what would
move it out. Past the target the plan may bring V down (the release pulls the
coin back toward the clamp). A step in which f_a lets a standing coin stand, whether V holds or
creeps inside f_a's dead band, adds no process noise to the filter: static friction holds the
coin, so the observations average the estimate down as σ/√n while the policy creeps.

**Chance constraint on overshoot** (``standoff_stds`` = z, :meth:`MPCPolicy._aim`). Under noise
the coin stops where the estimate says, give or take its std σ. The plan aims z σ − tolerance
short of the target on the side the coin comes from and holds V when the estimate is there, so
the coin ends past the window's far edge with probability Φ(−z) at most; as the observations
average σ down the aim closes on the target, and from σ ≤ tolerance / z it is the target.

**Re-centring** (``RECENTRE_STDS``). The hold starts on an estimate that is still noisy (at
σ = 0.1 mm its std is ~5–10 µm when the coin arrives), so the coin may stand near the edge
of the window, or just outside it, while the estimate says it is inside; the hysteresis
(``HOLD_STDS``) then keeps the hold. As the held observations average down, the policy
re-centres: while the estimate stands off the target, on either side, by more than
``RECENTRE_STDS`` of its own stds and more than ``RECENTRE_BAND`` × tolerance, it steps V by
``creep_V`` toward the target at every step until it stops doing so. The steps come in bursts, not
spaced out: a held FEM coin stands through small steps spread over many steps and moves under the
same steps in a row (docs/control.md;
``tests/control/test_filters.py::test_mpc_recentres_a_coin_its_estimate_holds_short``).

**Taper at the reach.** ``approach_m`` slows the push within that distance of the target,
so the coin does not coast past. Where the target lies at the edge of the coin's reach (the
model's coin, pushed at the full rate to the voltage limit, would stop within the tolerance
past the target) the taper is skipped: such a coin cannot coast far past, and on a coin whose
travel grows with the push rate the slower push costs the last µm (:meth:`MPCPolicy._at_reach`).
The stand-off (``standoff_stds``) gives way there too: a coin parked short of such a target
restarts only after the tip has reloaded, and no voltage is left for that stroke.

**Rate schedule** (``rate_V``, ``creep_V``, ``approach_m``). With a cruise rate below the plant's
ΔV_max (the FEM's 0.4 V per step, where a slow push drags a heavy coin along), the policy steps at
the plant's full rate while f_a, pushed that fast for ``MARGIN_V`` more, leaves the coin standing
(below the onset voltage moves nothing), then plans at the cruise rate, tapered within
``approach_m`` of the target down to ``creep_V``.

**Memory.** With an f_a whose step needs the DEA's state beyond its voltage (``f-memory``:
the tip's contact point P and friction T, :attr:`CoinDynamics.memory_units`) the plan's
state is ξ = (x, u, V, P, T). The plant shows neither: the policy tracks them as it tracks u,
by its own model step from the previous estimate under the applied voltage, starting from
the DEA at rest at the first voltage.

**Stalls** (``UNSTALL``). When the coin stands outside the hold band (``HOLD_BAND`` × the
tolerance; the tolerance itself without a hold band) and the solved plan
leaves V unchanged for its first step with the coin standing after it, the policy creeps
(``creep_V``) toward the target instead: such a plan sees the motion that more voltage
would bring only late in the horizon, not worth its ΔV penalty, and would be chosen again
at every step (the coin never restarts). With an f-memory f_a this happens after every stop
or reversal, where the tip must reload its friction by ~2 μ_b N c of stroke before the coin
moves (``tests/control/test_native_memory.py::test_a_plan_that_leaves_the_coin_standing_short_of_the_target_creeps``).

**Sweep** (``SWEEP``, :meth:`MPCPolicy._sweep`). Where the noise cannot be averaged down to the
window in time (``_unresolvable``: at σ = 1 mm the estimate's std is ~200 µm during the push), a
push that trusts the estimate jumps the window or stops short of it. The first push toward a target
then follows f_a open-loop under the voltages applied, with the bias filter's gain band
g ± ``standoff_stds`` of its std: the full rate while even the farthest-travelling plant of the
band stays out of the window after one more full step, then steps that move that plant at most
``SWEEP_STEP`` tolerances (a step shorter than the window cannot jump it), and V held once even
the least-travelling plant is past the window. The coin crosses the window (the paper's
criterion); where it stops past it is what the noise allows. f_a runs at the φ the episode starts
from; with ``learn`` the hold after a sweep measures the plant's gain against f_a's open-loop end
(:meth:`MPCPolicy._learn_sweep`), and the next sweep of the task starts its filter there.

**Restroke** (``RESTROKE_V``). Where the push reaches the voltage limit with the coin standing short
of the target (the mean of the observations there short by more than the tolerance plus ``HOLD_STDS``
of its std; in a sweep, while the gain band's least-travelling plant is not yet past the window) no
voltage is left to push on. The
policy then backs off ``RESTROKE_V`` and creeps back up at ``creep_V``: the coin's landing at the limit
depends on how fast the tip arrived, and a quasi-static push carries it further than the rate that left it
short (surrogate:C2 standing 10.1 µm short at 400 V: back 5 V, up at 0.5 V/step, and it passes the window
to 1,039 µm; up at 5 V/step it stops where it stood). The hold ends the creep once the estimate is inside
the hold band; in a sweep the creep goes on to the limit, through the window.

**Setpoints.** The target is read from ``info["target_m"]`` at every step, so a task that
moves the setpoint (push, push, pull back) re-plans at once.

**Learning across episodes** (``learn``, iterative learning control). The plant is
deterministic and a repeated task starts from the same state, so the voltage path that one
episode plays lands the coin where it landed before. An episode that ends with its estimate
within the approach distance (``approach_m``; the tolerance without one) of a single target, at most
``LEARN_STD`` tolerances uncertain, where the noise can be averaged down (``_unresolvable``), starts
what the next
episodes of the same task (target, tolerance, noise, step and rate) play instead of planning:
a rate schedule to an end voltage V_f, then the hold. The schedule runs at the plant's full rate
up to where that first episode's coin started, then at the cruise rate, tapered over the
approach distance (``approach_m`` in volts, by f_a's slope of the landing) down to ``creep_V``,
so that the coin slides on to its stop instead of sticking and slipping (without the taper the
landing is a staircase of V_f: surrogate:C2 noise-free settled 4/9 of episodes 2–10, 9/9 with
it). The first V_f is that episode's end (where it turned back, if it went past the target), moved
to the target by f_a's slope. Each scheduled episode holds V_f and averages its observations until
its first re-centring: the mean of a landing. The landing line, fitted by weighted least squares
to the landings and the first episode's end (a tolerance uncertain, ``LEARN_PATH_SHARE``) with
f_a's slope as a prior, gives the next V_f where it meets the target; the hold's estimate starts
from the line's value there and its variance, the observations refine it, and the re-centring
steps only where they move it confidently off the target. A task whose episode ended at the
voltage limit short of the target (``BEYOND_REACH``: no schedule reaches it) is planned in every
later episode without the approach taper: the plant has shown that the target lies at the edge of
its reach, where the slower push costs the last µm (:meth:`MPCPolicy._at_reach` judges the same
by f_a; surrogate:C2 noise-free ended 10 µm short at 400 V in 10/10 episodes, and reaches in
episodes 2–10 without the taper).
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field, fields, is_dataclass, replace

import torch

from deapull.control import mpc, native
from deapull.control.dynamics import COSTS, U_UNIT_M_S, V_UNIT_V, X_UNIT_M, CoinDynamics, coin_cost
from deapull.control.filters import EstimatorConfig
from deapull.control.inference import InferenceConfig, OnlineInference
from deapull.control.rollout_inference import RolloutInference
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
            raise InputError(f"the native MPC needs an f-coulomb or f-memory f_a and a C compiler (f_a is "
                             f"{model.kind!r}; compiler {'found' if native.library() is not None else 'missing'})")
        return native.native_dynamics(model, phi, dt, dv_max_V, v_max_V)
    return CoinDynamics(model, phi, dt, dv_max_V, v_max_V)


#: the terminal policy's fixed rules (module docstring; each has a test that fails without it):
#: hold once the estimate is inside HOLD_BAND × tolerance of the target, and go on holding while it
#: stays within that band plus HOLD_STDS of its own stds (noise alone does not end a hold);
HOLD_BAND, HOLD_STDS = 0.5, 4.5
#: in a hold, creep toward the target while the estimate is off it by more than RECENTRE_STDS of its
#: stds and RECENTRE_BAND × tolerance;
RECENTRE_STDS, RECENTRE_BAND = 1.5, 0.3
#: stand off at most MAX_WAIT steps per setpoint (none where σ/√MAX_WAIT stays above the std at
#: which the aim reaches the target);
MAX_WAIT = 1500
#: the rate schedule: the plant's full rate up to MARGIN_V below the voltage where f_a's coin starts,
#: then the cruise rate (a learnt schedule without an approach distance: creep from MARGIN_V short of
#: its end voltage)
MARGIN_V = 5.0
#: the first episode's end counts in the landing line with LEARN_PATH_SHARE × tolerance added to its
#: std (the schedule does not take its path)
LEARN_PATH_SHARE = 1.0
#: f_a's slope of the landing is the landing line's prior on its slope, with SLOPE_PRIOR × itself as
#: std: near the end of the reach f_a's slope can be a quarter of the plant's (surrogate:C1 at 399 V:
#: −3.1 against −11 µm/V), and the landings, spread over volts, outweigh it
#: (tests/control/test_mpc.py::test_the_landing_line_learns_a_slope_that_f_a_has_wrong)
SLOPE_PRIOR = 2.0
#: f_a's slope of the landing is a difference over SLOPE_SPAN_V: f_a's landings form a staircase
#: (stick-slip) whose steps are a few volts long, and a 2 V difference reads a step's flat
SLOPE_SPAN_V = 10.0
#: a planned episode starts the landing line if it ends within the approach distance (f_a's slope is the
#: line's prior there; the tolerance without one) with its estimate's std
#: at most LEARN_STD tolerances (the line weighs it by that variance), where the noise can be averaged
#: down at all (``_unresolvable``: at σ = 1 mm a landing's mean is ~100 µm uncertain, so a schedule
#: aimed by such landings misses the window; the sweep learns instead,
#: tests/control/test_mpc.py::test_a_repeated_sweep_starts_from_the_gain_its_hold_measured_and_stops_nearer)
LEARN_STD = 2.0
#: what ``learned`` holds for a task whose landing line stays outside the window even at the voltage
#: limit, or whose scheduled episode ended at the limit short of it: a schedule cannot reach it there,
#: so every later episode plans; a line that meets the window at the limit is scheduled to the limit
#: (tests/control/test_mpc.py::test_a_target_the_landing_line_meets_beyond_the_voltage_limit_is_planned_not_scheduled)
BEYOND_REACH = {"beyond_reach": True}
#: with a prior and the one-step loss, a field is planned at its estimate once its Cramér–Rao bound
#: on the relative error is below this (the paper's 10 % inference error), else at the prior's median
IDENTIFIED_CRLB = 0.1
#: creep toward the target when the solved plan holds V with the coin standing outside the hold band
#: (module docstring, "Stalls")
UNSTALL = True
#: sweep the window where the noise cannot be averaged down (MPCPolicy._sweep), at most SWEEP_STEP
#: tolerances per step for the farthest-travelling plant of the gain band (below 2: a step
#: shorter than the window cannot jump it; tests/control/test_mpc.py::
#: test_where_the_noise_cannot_be_averaged_down_the_push_sweeps_through_the_window)
SWEEP, SWEEP_STEP = True, 1.5
#: a restroke where the coin stands short of the target at the voltage limit (module docstring,
#: "Restroke"): RESTROKE_V back, then creep_V per step up again, at most RESTROKE_MAX per setpoint, once the
#: coin has stood RESTROKE_WAIT steps at the limit; in a sweep once, SWEEP_RESTROKE_V back
#: (tests/control/test_mpc.py::
#: test_a_coin_standing_short_of_the_target_at_the_voltage_limit_is_restroked_at_the_creep_rate)
RESTROKE_V, RESTROKE_WAIT, RESTROKE_MAX, SWEEP_RESTROKE_V = 5.0, 5, 3, 2.0


#: the MPC's inference when none is given: Levenberg–Marquardt on the one-step loss
MPC_INFERENCE = InferenceConfig(optimizer="lm")


@dataclass(frozen=True)
class MPCConfig:
    """Settings of the MPC policy: the solver, the estimator, the inference and the terminal policy.

    A preset's ``[mpc]`` table (``[mpc.estimator]``, ``[mpc.inference]``) and ``--set mpc.KEY=VALUE``
    set them (:func:`mpc_config`).

    Attributes
    ----------
    horizon, iterations : int
        Steps planned ahead and iLQR iterations per control step (paper: 20, 20).
    cost : {"scaled", "paper"}
        :func:`~deapull.control.dynamics.coin_cost`.
    engine : {"auto", "native", "torch"}
        Where f_a's steps, Jacobians and the iLQR run: ``native`` the compiled solver of
        :mod:`deapull.control.native` (f-coulomb and f-memory; the same plans to round-off,
        ~400–1,000× faster), ``torch`` :func:`mpc.solve` on :class:`CoinDynamics`, ``auto`` native
        where it is available.
    estimator : EstimatorConfig
        What the plan starts from (:class:`~deapull.control.filters.EstimatorConfig`): ``bias``
        (default) the offset-free estimate of the position and of f_a's gain error, with the
        terminal policy below; ``kf`` a position-only Kalman estimate on f_a, ``none`` the
        observation, both without the terminal policy (the plain MPC, ``mpc+kf``).
    inference : InferenceConfig or None
        The online inference of φ (Algorithm 2; ``loss``, ``every`` and ``crlb_every`` are its own
        settings); None: plan with the φ given to the policy.
    rate_V : float
        The cruise |ΔV| per step once the coin moves (V; 0: the plant's ΔV_max), in the plan and
        on the plant; below the onset, where f_a says the coin stands, the plant's ΔV_max. A
        heavy coin is carried further by a slow push: at the plant's 5 V per step the tip slips
        over it, at the sweep's 0.4 V per step it is dragged along (docs/control.md).
    creep_V : float
        The slowest |ΔV| per step outside the hold (V); smaller planned steps are raised to it.
    approach_m : float
        Within this distance (m) of the target |ΔV| is limited to the rate × distance /
        ``approach_m`` (not below ``creep_V``), so the coin arrives slowly and does not coast
        past (0: no limit).
    standoff_stds : float
        The chance constraint on overshoot (:meth:`MPCPolicy._aim`): under noise, aim this many
        stds of the position estimate, less the tolerance, short of the target, and close on it as
        the held observations average the estimate down (0: off).
    reach_gate : bool
        Let the stand-off and the taper give way where f_a says the target lies at the edge of
        the reach (:meth:`MPCPolicy._at_reach`). Off for a plant that can go further than f_a at
        the planning φ says (the surrogates at 5 V per step: the prior's median puts −1 mm at
        C1's edge).
    learn : bool
        Learning across the episodes of a repeated task (module docstring).
    """

    horizon: int = 20
    iterations: int = 20
    cost: str = "scaled"
    engine: str = "auto"
    estimator: EstimatorConfig = field(default_factory=EstimatorConfig)
    inference: InferenceConfig | None = field(default_factory=lambda: MPC_INFERENCE)
    rate_V: float = 0.0
    creep_V: float = 0.5
    approach_m: float = 0.0
    standoff_stds: float = 0.0
    reach_gate: bool = True
    learn: bool = True

    def __post_init__(self):
        if self.engine not in ENGINES:
            raise InputError(f"mpc.engine = {self.engine!r}: choose one of {', '.join(ENGINES)}")
        if self.cost not in COSTS:
            raise InputError(f"mpc.cost = {self.cost!r}: choose one of {', '.join(COSTS)}")
        if int(self.horizon) != self.horizon or self.horizon < 1:
            raise InputError(f"mpc.horizon = {self.horizon!r}: must be an integer >= 1")
        if int(self.iterations) != self.iterations or self.iterations < 0:
            raise InputError(f"mpc.iterations = {self.iterations!r}: must be an integer >= 0")
        for name in ("rate_V", "approach_m", "standoff_stds"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise InputError(f"mpc.{name} = {value!r}: must be a finite number >= 0")
        if not (math.isfinite(self.creep_V) and self.creep_V > 0):
            raise InputError(f"mpc.creep_V = {self.creep_V!r}: must be a finite number > 0 (V per step)")

    @property
    def terminal(self) -> bool:
        """Whether the terminal policy (hold, re-centre, stand-off, taper, rate, learning) acts: with
        the offset-free estimator only."""
        return self.estimator.kind == "bias"


def mpc_config(table: dict, base: MPCConfig = MPCConfig(), where: str = "mpc") -> MPCConfig:
    """``base`` with a nested table of settings (a preset's ``[mpc]``, ``--set mpc.KEY=VALUE``) applied:
    ``estimator`` and ``inference`` are sub-tables of their configs' fields. An unknown key, or a value
    of the wrong type, raises :class:`InputError` naming it and what is allowed."""
    return _apply(base, table, where)


def _apply(config, table: dict, where: str):
    allowed = {f.name: f for f in fields(config)}
    changes = {}
    for key, value in table.items():
        if key not in allowed:
            raise InputError(f"{where}.{key}: unknown key; allowed: {', '.join(allowed)}")
        current = getattr(config, key)
        if key == "inference" and current is None and isinstance(value, dict):
            current = MPC_INFERENCE
        if is_dataclass(current):
            if not isinstance(value, dict):
                raise InputError(f"{where}.{key} = {value!r}: expected a table of {type(current).__name__} keys")
            changes[key] = _apply(current, value, f"{where}.{key}")
        else:
            changes[key] = _typed(value, current, f"{where}.{key}")
    return replace(config, **changes)


def _typed(value, current, where: str):
    """``value`` as the type of the field's ``current`` value (an int is a float's too; a list is a tuple's)."""
    if current is None or isinstance(current, dict):
        return tuple(value) if isinstance(value, list) else value
    kind = type(current)
    if kind is bool:
        ok = isinstance(value, bool)
    elif kind is float:
        ok, value = isinstance(value, (int, float)) and not isinstance(value, bool), value
        value = float(value) if ok else value
    elif kind is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif kind is tuple:
        ok, value = isinstance(value, (list, tuple)), tuple(value) if isinstance(value, (list, tuple)) else value
    else:
        ok = isinstance(value, kind)
    if not ok:
        raise InputError(f"{where} = {value!r}: expected {kind.__name__}")
    return value


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
        self.name = "mpc+kf" if config.estimator.kind == "kf" else "mpc"
        if config.inference is None and phi is None:
            raise InputError("an MPC without inference needs the φ to plan with")
        self.fixed_phi = None if phi is None else model.check_phi(phi).to(dtype=torch.float64)
        self.inference = None
        self.spec = None
        self.previous = None
        #: what earlier episodes of each task taught (:meth:`_learn`): task -> {the schedule's shape and
        #: V_f, the landing line's points and its value x_f and variance x_var at V_f, g and its variance}
        self.learned: dict = {}
        self.swept: dict = {}        # task key -> the gain a sweep's hold measured {gain, gain_var}
        self.sweep_hold = None
        self.schedule = None
        #: the scheduled episode's held observations at its end voltage: {V_f, n, sum, open}
        self.landing = None

    @staticmethod
    def _task_key(spec) -> tuple:
        return (float(spec.target_m), float(spec.tolerance_m), float(spec.noise_std_m), float(spec.dt_s),
                float(spec.dv_max_V))

    def _learn(self) -> None:
        """What the episode that just ended tells the next one of its task (module docstring,
        "Learning across episodes"). A planned episode that ended within the approach distance of its
        one target (by its own estimate, at most ``LEARN_STD`` tolerances uncertain) gives the first point of the
        landing line: where it ended, or where it turned back if it went past, and f_a's slope. A
        scheduled episode adds the mean of its held observations where the schedule landed. The
        next end voltage is where the line fitted to them crosses the target (:meth:`_landing_fit`)."""
        if not (self.config.learn and self.config.terminal) or self.spec is None or self.previous is None or self.bias is None:
            return
        x, _, V = self.previous
        if self.target_m != float(self.spec.target_m) or self.moved_target:
            return
        key = self._task_key(self.spec)
        entry, landing = self.learned.get(key), self.landing
        if entry is BEYOND_REACH:
            return
        if self.restrokes and not self._unresolvable():
            self.learned[key] = BEYOND_REACH     # the push reached the voltage limit short of the target
            return
        if entry is not None and landing is not None and landing["n"] > 0:
            if V >= self.v_max_V and (x - self.target_m) * math.copysign(1.0, entry["slope"]) < -self.tolerance_m:
                self.learned[key] = BEYOND_REACH     # the hold went to the voltage limit short of the target
                return
            entry["landings"].append((landing["V_f"], landing["sum"] / landing["n"],
                                      max(self.spec.noise_std_m, 1e-9) ** 2 / landing["n"]))
        elif (entry is None and not self._unresolvable()
              and abs(x - self.target_m) <= max(self.tolerance_m, self.approach_m)
              and self.estimate_std_m <= LEARN_STD * self.tolerance_m):
            V_ref, x_ref = (V, x) if self.turned is None else self.turned
            # the schedule's shape: fast up to where this episode's coin started, and the approach
            # distance as a taper in volts, by f_a's slope of the landing
            shape = {"V_start": self.V_started, "taper_V": 0.0}
            slope = self._landing_slope(shape, V_ref)
            if slope is not None and self.approach_m > 0:
                shape["taper_V"] = self.approach_m / abs(slope)
                slope = self._landing_slope(shape, V_ref)
            if slope is None:
                return
            # the planned path is not the schedule's: its end counts as a landing LEARN_PATH_SHARE
            # tolerances uncertain
            entry = {"slope": slope, "landings": [], **shape,
                     "start": (V_ref, x_ref, float(self.bias.P[0, 0]) + (LEARN_PATH_SHARE * self.tolerance_m) ** 2)}
        else:
            return
        V_f, x_f, x_var = self._landing_fit(entry)
        if V_f >= self.v_max_V and abs(x_f - self.target_m) > self.tolerance_m:
            # at the voltage limit the line stays outside the window: beyond the schedule's reach
            self.learned[key] = BEYOND_REACH
            return
        entry.update(V_f=V_f, x_f=x_f, x_var=x_var, gain=self.bias.gain, gain_var=float(self.bias.P[1, 1]))
        self.learned[key] = entry

    def _landing_fit(self, entry: dict) -> tuple[float, float, float]:
        """The landing line x = c + b (V − V̄) by weighted least squares over the landings seen (each
        mean weighted by its count over σ²) and the first episode's end, with f_a's slope as a prior
        on b (:data:`SLOPE_PRIOR` × its size as std): the end voltage where it crosses the target,
        clipped to the voltage range, and the line's value and variance there (what the next hold
        starts from)."""
        points = [entry["start"], *entry["landings"]]
        V_mean = sum(p[0] / p[2] for p in points) / sum(1.0 / p[2] for p in points)
        b0 = entry["slope"]
        # normal equations in (c, b): the data, and the prior (b − b0)² / (SLOPE_PRIOR b0)²
        A = torch.zeros(2, 2, dtype=torch.float64)
        r = torch.zeros(2, dtype=torch.float64)
        for V, m, var in points:
            row = torch.tensor([1.0, V - V_mean], dtype=torch.float64)
            A += torch.outer(row, row) / var
            r += row * m / var
        A[1, 1] += 1.0 / (SLOPE_PRIOR * b0) ** 2
        r[1] += b0 / (SLOPE_PRIOR * b0) ** 2
        cov = torch.linalg.inv(A)
        c, b = (cov @ r).tolist()
        if not b * b0 > 0:                  # the data say the wrong sign: keep f_a's
            b = b0

        V_f = min(max(V_mean + (self.target_m - c) / b, 0.0), self.v_max_V)
        row = torch.tensor([1.0, V_f - V_mean], dtype=torch.float64)
        return V_f, c + b * (V_f - V_mean), float(row @ cov @ row)

    def _schedule_nu(self, shape: dict, V_f: float) -> torch.Tensor:
        """The learnt episode's rate schedule (:meth:`_schedule_step`, what :meth:`act` plays) from rest
        at 0 V to ``V_f`` as ν (1, T, 1), of the ``shape`` {V_start, taper_V}."""
        steps, V, entry = [], 0.0, {**shape, "V_f": V_f}
        while V_f - V > 1e-9:
            dV = self._schedule_step(entry, V)
            steps.append(dV / self.dv_max_V)
            V += dV
        return torch.tensor(steps, dtype=torch.float64).reshape(1, -1, 1)

    def _schedule_step(self, entry: dict, V: float) -> float:
        """ΔV of the learnt episode's rate schedule at ``V`` (module docstring): the plant's full
        rate below where the first episode's coin started, then the cruise rate, tapered over the
        last ``taper_V`` volts (the approach distance in volts) down to ``creep_V`` so that the
        coin slides on to its stop rather than sticking and slipping; without an approach
        distance, the cruise rate up to ``MARGIN_V`` short of ``V_f`` and ``creep_V`` from there."""
        gap = entry["V_f"] - V
        if V + self.plant_dv_max_V <= entry["V_start"]:
            return min(self.plant_dv_max_V, gap)
        creep = min(self.config.creep_V, self.dv_max_V)
        if entry["taper_V"] > 0:
            return min(self.dv_max_V, max(creep, self.dv_max_V * gap / entry["taper_V"]), gap)
        return min(self.dv_max_V if gap > MARGIN_V else creep, gap)

    def _landing_slope(self, shape: dict, V_f: float) -> float | None:
        """dx/dV of where the schedule to ``V_f`` lands, by f_a at the planning φ scaled by the
        episode's 1 + g (m/V; a difference over SLOPE_SPAN_V within [0, the voltage limit]); None where
        f_a's coin does not move there (then nothing is learnt)."""
        low = min(max(V_f - SLOPE_SPAN_V / 2, 0.0), self.v_max_V - SLOPE_SPAN_V)
        rest = self.dynamics.state(0.0, 0.0, 0.0, None)
        ends = [float(self._roll(rest, self._schedule_nu(shape, V))[0, -1, 0]) * X_UNIT_M
                for V in (low, low + SLOPE_SPAN_V)]
        slope = (1.0 + self.gain_error) * (ends[1] - ends[0]) / SLOPE_SPAN_V
        return slope if abs(slope) > 1e-9 else None

    def reset(self, spec) -> None:
        cfg = self.config
        self._learn()
        self._learn_sweep()
        # the sweep (_sweep): f_a's φ and open-loop state under the applied voltages, and its hold
        self.sweep_phi, self.open_xi, self.sweep_hold = None, None, None
        self.moved_target, self.landing = False, None
        self.turned, self.V_peak = None, 0.0    # where a planned episode first turned back past the target: (V, x)
        self.V_started = 0.0                    # where the rate schedule's fast start ended
        self.schedule = self.learned.get(self._task_key(spec)) if cfg.learn and cfg.terminal else None
        beyond = self.schedule is BEYOND_REACH
        if beyond:
            self.schedule = None
        self.spec, self.target_m, self.tolerance_m = spec, float(spec.target_m), float(spec.tolerance_m)
        self.dt, self.dv_max_V, self.v_max_V = float(spec.dt_s), float(spec.dv_max_V), float(spec.v_max_V)
        self.plant_dv_max_V = self.dv_max_V
        # the terminal policy's rules, read here so that a test can switch one off (module constants)
        on = cfg.terminal
        self.hold_band, self.recentre_stds = (HOLD_BAND, RECENTRE_STDS) if on else (0.0, 0.0)
        self.approach_m, self.standoff_stds = (cfg.approach_m, cfg.standoff_stds) if on else (0.0, 0.0)
        if beyond:
            # an earlier episode of this task ended at the voltage limit short of the target: it lies
            # at the edge of the plant's reach, where the taper costs the last µm (_at_reach, judged
            # by the plant instead of f_a)
            self.approach_m = 0.0
        if cfg.terminal and cfg.rate_V > 0:  # the plan's ΔV_max: the model sees the rate the plant gets
            self.dv_max_V = min(self.dv_max_V, cfg.rate_V)
        noise = float(spec.noise_std_m)
        self.noisy = noise > 0
        self.kalman = self.bias = None
        if cfg.estimator.kind == "bias":
            self.bias = cfg.estimator.make(noise)
        else:
            self.kalman = cfg.estimator.make(noise)
        if cfg.inference is not None:
            # a transition counts as moving (stick hinge) only beyond 3 noise stds
            # and the prior's smallest residual std is the noise's
            settings = replace(cfg.inference, motion_threshold_m=max(cfg.inference.motion_threshold_m, 3 * noise),
                               observation_std_m=max(cfg.inference.observation_std_m, noise))
            if settings.loss == "rollout":
                self.inference = RolloutInference(self.model, settings, self.dt, float(spec.dv_max_V),
                                                  self.v_max_V, settings.every)
            elif not isinstance(self.inference, OnlineInference) or self.inference.dt != self.dt \
                    or self.inference.config != settings:
                self.inference = OnlineInference(self.model, settings, self.dt)
            self.inference.reset()
        infer = cfg.inference is not None
        self._crlb = {f"crlb_{f}": math.nan for f in self.inference.fields} if infer else {}
        phi = self._planning_phi() if infer else self.fixed_phi
        self.dynamics = make_dynamics(self.model, phi, self.dt, self.dv_max_V, self.v_max_V, cfg.engine)
        self.native = callable(getattr(self.dynamics, "solve", None))
        self.cost = self._cost(self.target_m)
        self.plan = None
        self.holding = False
        self.side, self.waited = math.copysign(1.0, 0.0 - self.target_m), 0   # the coin starts at x = 0
        self.previous = None          # (x, u, V) estimate of the previous step
        self.memory = None            # f_a's memory entries (scaled) after that step; None: at rest
        self.reach_end = None         # this step's full-rate rollout to the voltage limit (_at_reach)
        self.started = not self.dv_max_V < self.plant_dv_max_V   # the rate schedule's fast start is over
        self.solve_ms, self.inference_ms = [], []
        self._clear_restroke()
        self.sweep_crossed = False    # the sweep's gain band has its least-travelling plant past the window

    def inferred(self) -> dict:
        """The current φ and each inferred field's Cramér–Rao bound on its relative error
        (``crlb_<field>``, :meth:`_judge`): what the data can say, beside what the estimate says."""
        if self.inference is None:
            return {}
        return {**self.inference.estimate(), **self._crlb}

    def _judge(self) -> None:
        """Every ``crlb_every`` transitions once the coin has moved: the bounds from the buffer's
        Fisher information at the current φ and :meth:`_residual_std` (inf where the data do
        not identify a field)."""
        every = self.config.inference.crlb_every
        if every and self.inference.moved and self.inference.transitions % every == 0:
            self._crlb = {f"crlb_{f}": v for f, v in self.inference.crlb(self._residual_std()).items()}

    def _residual_std(self) -> float:
        """The std of one transition's position residual (m) that the bound assumes: the larger of
        the observation noise and the model's RMS misfit over the buffer at the current φ (as
        in weighted least squares with unknown variance; 1 nm at least)."""
        return max(self.spec.noise_std_m, self.inference.misfit_m(), 1e-9)

    def _planning_phi(self) -> Phi:
        """The φ the plan uses. Without a prior, the inference's estimate (the paper). With one
        and the output-error loss (``inference.loss = "rollout"``), the MAP estimate: the prior holds
        what the data leave open, and the data move what they determine (the onset), so no gate
        is needed (docs/control.md, "What the data can tell"). With one and the one-step loss,
        whose estimate is biased under noise (errors in variables), each field the data identify
        (Cramér–Rao bound below ``IDENTIFIED_CRLB``) takes the estimate and every other field
        stays at the prior's median (``inference.crlb_every`` sets how often it is judged; before the first
        judgement every field is at the prior)."""
        prior = self.inference.config.prior
        if not prior or self.inference.config.loss == "rollout":
            return self.inference.phi
        estimate = self.inference.estimate()
        values = {}
        for f in self.model.phi_fields:
            bound = self._crlb.get(f"crlb_{f}", math.nan)
            anchored = f in prior and not bound < IDENTIFIED_CRLB
            values[f] = torch.tensor(prior[f][0] if anchored else estimate[f], dtype=torch.float64)
        return Phi(**values)

    def _aim(self, xi0, x: float, V: float) -> float:
        """Where the plan goes: a chance constraint on overshoot. The coin stops where the estimate
        says, give or take its std σ, so the plan aims ``standoff_stds`` × σ − tolerance short of the
        target, on the side the coin comes from: it then stops past the far edge of the window with
        probability Φ(−``standoff_stds``) at most. As held observations average σ down the aim
        closes on the target, which it reaches at σ = tolerance / ``standoff_stds``. At the target
        itself: where the target lies at the edge of the reach (:meth:`_at_reach`; a coin stopped
        short there restarts only after the tip has reloaded, and no voltage is left to make up that
        stroke: ``tests/control/test_mpc.py::test_the_stand_off_gives_way_at_the_edge_of_the_reach``),
        and where waiting cannot help (:meth:`_unresolvable`), and after
        ``MAX_WAIT`` steps at the stand-off."""
        margin = self.standoff_stds * self.estimate_std_m - self.tolerance_m
        if self.standoff_stds <= 0 or margin <= 0 or self.waited >= MAX_WAIT or self._unresolvable():
            return self.target_m
        if self._at_reach(xi0, x, V, within=self.standoff_stds * self.estimate_std_m + self.approach_m):
            return self.target_m
        return self.target_m + self.side * margin

    def _clear_restroke(self) -> None:
        """No restroke yet for this setpoint: none running, none made, nothing observed at the limit."""
        self.restroke, self.restrokes = False, 0
        self._leave_limit()

    def _leave_limit(self) -> None:
        """Start counting afresh at the voltage limit: its steps, and the observations after the wait."""
        self.at_limit = {"steps": 0, "n": 0, "sum": 0.0}

    def _restroke(self, x: float, V: float, observed: float) -> float | None:
        """ΔV of a restroke (module docstring, "Restroke"), None outside one: back off ``RESTROKE_V``
        once the coin stands at the voltage limit short of the target, then ``creep_V`` per step up to
        the limit (in a planned push only until the estimate ``x`` is inside the hold band, where the
        hold takes over). Short: after ``RESTROKE_WAIT`` steps at the limit (the coin's coast), the
        mean of the ``observed`` positions since then is short by more than the tolerance plus
        ``HOLD_STDS`` of its std σ/√n (tested at every step, so as wide as the hold's own test); in a
        sweep, where that mean cannot tell, the gain band's least-travelling plant is not past the
        window."""
        if not self.config.terminal or RESTROKE_MAX <= 0 or self.side < 0:
            return None
        blind, seen = self._blind(), self.at_limit
        if self.restroke:
            if V < self.v_max_V and (blind or self.side * (x - self.target_m) > self.hold_band * self.tolerance_m):
                return min(self.config.creep_V, self.dv_max_V, self.v_max_V - V)
            self.restroke = False
            self._leave_limit()
            return None
        if V < self.v_max_V or self.restrokes >= (1 if blind else RESTROKE_MAX):
            self._leave_limit()
            return None
        seen["steps"] += 1
        if seen["steps"] > RESTROKE_WAIT:
            seen["n"], seen["sum"] = seen["n"] + 1, seen["sum"] + observed
        if blind:
            short = seen["steps"] > RESTROKE_WAIT and not self.sweep_crossed
        else:
            n = seen["n"]
            short = n > 0 and (self.side * (seen["sum"] / n - self.target_m)
                               > self.tolerance_m + HOLD_STDS * self.spec.noise_std_m / math.sqrt(n))
        if not short:
            return None
        self.restroke, self.restrokes, self.holding = True, self.restrokes + 1, False
        return -min(SWEEP_RESTROKE_V if blind else RESTROKE_V, V)

    def _unresolvable(self) -> bool:
        """Whether held observations cannot average the estimate down to tolerance /
        ``standoff_stds`` within ``MAX_WAIT`` steps (σ/√MAX_WAIT above it, at σ = 1 mm and a 10 µm
        window: 26 µm after 1,500 steps): waiting at a stand-off point then only delays the reach."""
        need = self.tolerance_m / max(self.standoff_stds, 1.0)
        return self.spec.noise_std_m / math.sqrt(max(MAX_WAIT, 1)) > need

    def _wait(self, x: float, aim: float) -> bool:
        """Hold V at the stand-off point while the observations average the estimate down
        (at most ``MAX_WAIT`` steps per setpoint): once the estimate is at or past the
        stand-off point on the way to the target."""
        if aim == self.target_m:
            return False
        if self.side * (x - aim) <= self.hold_band * self.tolerance_m:
            self.waited += 1
            return True
        return False

    def _recentre(self, x: float) -> float:
        """ΔV during a hold: one ``creep_V`` toward the target when the estimate ``x`` stands
        off it by more than ``RECENTRE_STDS`` stds and ``RECENTRE_BAND`` × tolerance, else 0
        (module docstring)."""
        cfg = self.config
        off = x - self.target_m
        if self.recentre_stds <= 0 or abs(off) <= max(RECENTRE_BAND * self.tolerance_m,
                                                      self.recentre_stds * self.estimate_std_m):
            return 0.0
        return math.copysign(min(cfg.creep_V, self.dv_max_V), off)

    def _blind(self) -> bool:
        """Whether the push is a sweep (:meth:`_sweep`): a first push toward one target where the noise
        cannot be averaged down to the window (``_unresolvable``), before anything was learnt."""
        return (self.config.terminal and SWEEP and self.bias is not None and self.side > 0
                and not self.moved_target and self.schedule is None and self._unresolvable())

    def _sweep(self, V: float, observed: float) -> float:
        """ΔV of the sweep: where the observations cannot place the coin within the window in time, the
        push follows f_a open-loop (from rest, under the voltages applied) and the bias filter's gain
        band, g ± ``standoff_stds`` of its std: the plant's coin lies between (1 + g_lo) and
        (1 + g_hi) × f_a's (module docstring, "Sweep"). The full rate while even the
        farthest-travelling plant stays out of the window after one more full step; then steps
        that move that plant at most SWEEP_STEP ×
        tolerance, so that every plant in the band crosses the window rather than jumping it; and V
        held once even the least-travelling plant is past the window's far edge."""
        nu = lambda dV: torch.full((1, 1, 1), dV / self.dv_max_V, dtype=torch.float64)
        if self.sweep_phi is None:          # f_a open-loop at the φ the episode starts from, not the estimate's
            self.sweep_phi = self.dynamics.phi
        phi, self.dynamics.phi = self.dynamics.phi, self.sweep_phi
        try:
            if self.open_xi is None:
                before, self.open_xi = None, self.dynamics.state(0.0, 0.0, V, None)
            else:
                before = float(self.open_xi[0, 0]) * X_UNIT_M
                applied = V - float(self.open_xi[0, 2]) * V_UNIT_V
                self.open_xi = self._roll(self.open_xi, nu(applied))[:, -1, :]
            x = float(self.open_xi[0, 0]) * X_UNIT_M
            full = min(self.dv_max_V, self.v_max_V - V)
            step = float(self._roll(self.open_xi, nu(full))[0, -1, 0]) * X_UNIT_M - x if full > 0 else 0.0
        finally:
            self.dynamics.phi = phi
        spread = self.standoff_stds * math.sqrt(max(float(self.bias.P[1, 1]), 0.0))
        g = self.gain_error
        low, high = max(1.0 + g - spread, 0.0), 1.0 + g + spread
        self.sweep_crossed = low * x <= self.target_m - self.tolerance_m
        if full <= 0 or self.sweep_crossed:
            # held: where f_a's coin stands, the observations measure the plant's travel against it
            if before == x and x != 0.0:
                hold = self.sweep_hold
                if hold is None or hold["V"] != V:
                    hold = self.sweep_hold = {"V": V, "n": 0, "sum": 0.0}
                hold["n"], hold["sum"], hold["x_open"] = hold["n"] + 1, hold["sum"] + observed, x
            return 0.0
        if high * (x + step) >= self.target_m + self.tolerance_m or step >= 0:
            return full
        # a step's size rests on f_a's local slope, which a measured gain (a ratio of positions) does
        # not correct: it is bounded with the filter's prior band
        steep = 1.0 + g + self.standoff_stds * math.sqrt(self.bias.p_g)
        return min(full, full * SWEEP_STEP * self.tolerance_m / (max(high, steep) * abs(step)))

    def _learn_sweep(self) -> None:
        """What a swept episode's hold tells the next sweep of its task (``learn``): the mean of the
        held observations over f_a's open-loop end, g = x̄ / x_f_a − 1, with variance σ² / (n x_f_a²),
        combined with what earlier sweeps measured; the next episode's bias filter starts from it."""
        hold = self.sweep_hold
        if not (self.config.learn and hold and hold["n"] > 0 and self.spec is not None) or self.moved_target:
            return
        x_open = hold["x_open"]
        gain = hold["sum"] / hold["n"] / x_open - 1.0
        var = max(self.spec.noise_std_m, 1e-9) ** 2 / (hold["n"] * x_open ** 2)
        key = self._task_key(self.spec)
        seen = self.swept.get(key)
        if seen is not None:
            w = 1.0 / seen["gain_var"] + 1.0 / var
            gain, var = (seen["gain"] / seen["gain_var"] + gain / var) / w, 1.0 / w
        self.swept[key] = {"gain": gain, "gain_var": var}

    def _roll(self, xi0, nu):
        """f_a's rollout ξ (B, T+1, n) from ξ0 under ν: the compiled one, else :func:`mpc.rollout`."""
        return self.dynamics.rollout(xi0, nu) if self.native else mpc.rollout(self.dynamics, xi0, nu)

    def _at_reach(self, xi0, x: float, V: float, within: float | None = None) -> bool:
        """Whether the target lies at the edge of the coin's reach: pushed at the full rate up to
        the voltage limit, the model's coin (its travel scaled by 1 + g) would stop no more than
        the tolerance past the target. Then the approach taper does not apply: a coin that
        cannot go much further cannot coast past, and the slower push costs the last µm
        (``tests/control/test_mpc.py::test_the_approach_taper_gives_way_at_the_edge_of_the_reach``).
        Judged only while the coin is short of the target by less than ``within`` (m; default
        ``approach_m``)."""
        if not self.config.reach_gate:
            return False
        within = self.approach_m if within is None else within
        if not (self.side > 0 and x > self.target_m and abs(x - self.target_m) < within):
            return False
        steps = math.ceil(max(self.v_max_V - V, 0.0) / self.dv_max_V)
        if steps == 0:
            return True
        if self.reach_end is None:          # once per step: the stand-off and the taper both ask
            ones = torch.ones(1, steps, 1, dtype=torch.float64)
            self.reach_end = float(self._roll(xi0, ones)[0, -1, 0]) * X_UNIT_M
        reach = x + (1.0 + self.gain_error) * (self.reach_end - x)
        return reach > self.target_m - self.tolerance_m

    def _below_onset(self, xi0, x: float, V: float) -> bool:
        """The rate schedule's fast start: whether f_a, pushed at the plant's full rate, leaves the
        coin standing for ``MARGIN_V`` more (then the step is the plant's full rate, not the cruise
        rate, since voltage below the onset moves nothing). Once it does not, the start is over for
        this setpoint (:attr:`started`)."""
        if self.side < 0 or x <= self.target_m or V >= self.v_max_V:
            self.started = True
            return False
        steps = math.ceil(MARGIN_V / self.plant_dv_max_V) + 1
        nu = torch.full((1, steps, 1), self.plant_dv_max_V / self.dv_max_V, dtype=torch.float64)
        path = self._roll(xi0, nu)[0, :, 0] * X_UNIT_M
        if float((path - x).abs().max()) > 1e-9:
            self.started, self.V_started = True, V
        return not self.started

    def _cost(self, model_target_m: float):
        cfg = self.config
        return coin_cost(model_target_m, cfg.cost, memory=self.dynamics.n - 3)

    @property
    def estimate_std_m(self) -> float:
        """Std of the position estimate (m): the bias filter's, else 0."""
        return self.bias.std_m if self.bias is not None and self.noisy else 0.0

    @property
    def gain_error(self) -> float:
        """The bias filter's g (0 without one): the plant moves (1 + g) × f_a's step."""
        return self.bias.gain if self.bias is not None else 0.0

    def _estimate(self, x: float, V: float) -> tuple[float, float]:
        """(x, u) to plan from, given the observed x and the applied V (module docstring)."""
        if self.previous is None:
            self.memory = None
            if self.bias is not None:
                if self.schedule is not None:
                    return self.bias.reset(x, self.schedule["gain"], self.schedule["gain_var"]), 0.0
                swept = self.swept.get(self._task_key(self.spec)) if self._blind() else None
                if swept is not None:
                    return self.bias.reset(x, swept["gain"], swept["gain_var"]), 0.0
                return self.bias.reset(x), 0.0
            return (x if self.kalman is None else self.kalman.reset(x)), 0.0
        x0, u0, V0 = self.previous
        memory = self.dynamics.n > 3
        if not self.noisy and self.bias is None and not memory:
            return x, (x - x0) / self.dt
        with torch.no_grad():
            pred = self.dynamics(self.dynamics.state(x0, u0, V0, self.memory),
                                 torch.tensor([[(V - V0) / self.dv_max_V]], dtype=torch.float64))[0]
        if memory:                          # the tip's state after the applied step, by f_a
            self.memory = pred[3:].clone()
            if not self.noisy and self.bias is None:
                return x, (x - x0) / self.dt
        x_pred, u_pred = float(pred[0]) * X_UNIT_M, float(pred[1]) * U_UNIT_M_S
        if self.bias is not None:
            x_obs = x
            x = self.bias.update(x_pred - x0, x_obs, held=abs(u0) < 1e-9, fall_V=max(V0 - V, 0.0), hold_V=V == V0)
            if not self.noisy:
                return x_obs, (x_obs - x0) / self.dt
            return x, u_pred
        if self.kalman is not None:
            x = self.kalman.update(x_pred, x)
        return x, u_pred

    @torch.no_grad()
    def act(self, obs, info) -> float:
        cfg = self.config
        x, V = self.spec.position_of(obs), float(info["V_V"])
        observed = x
        target = float(info.get("target_m", self.target_m))
        if target != self.target_m:          # a new setpoint: plan afresh
            self.target_m, self.plan, self.holding = target, None, False
            self.moved_target, self.schedule = True, None
            self.side = math.copysign(1.0, (self.previous[0] if self.previous else x) - target)
            self.waited = 0
            self._clear_restroke()
        if cfg.inference is not None:
            start = time.perf_counter()
            self.inference.observe(x, V)
            self.inference.update()
            self._judge()
            self.dynamics.phi = self._planning_phi()
            self.inference_ms.append(1e3 * (time.perf_counter() - start))
        start = time.perf_counter()
        x, u = self._estimate(x, V)
        self.previous = (x, u, V)
        if V > self.V_peak:
            self.V_peak = V
        elif V < self.V_peak and self.turned is None and self.side * (x - self.target_m) < 0:
            self.turned = (self.V_peak, x)      # turned back past the target
        xi0 = self.dynamics.state(x, u, V, self.memory)
        self.reach_end = None
        dV = self._restroke(x, V, observed)
        if dV is not None:
            self.solve_ms.append(1e3 * (time.perf_counter() - start))
            return dV
        if self._blind():
            self.solve_ms.append(1e3 * (time.perf_counter() - start))
            return self._sweep(V, observed)
        T = cfg.horizon
        ramp = torch.ones(1, T, 1, dtype=torch.float64)
        # hold (hysteresis): start once the estimate is inside the band, and go on while it stays
        # within the band plus its own uncertainty; at constant V static friction holds
        # the coin and the estimate's std shrinks as the observations average
        if self.schedule is not None:       # a learnt episode: the rate schedule to V_f, then the hold
            if self.schedule["V_f"] - V > 1e-9:
                self.solve_ms.append(1e3 * (time.perf_counter() - start))
                return self._schedule_step(self.schedule, V)
            # the hold starts where the landing line puts the coin, x_f, with the line's variance there,
            # not from the estimate carried through the schedule (it rests on g over a path the filter
            # has not seen); held, the observations refine it, and they are the next landing
            x = self.bias.reset(self.schedule["x_f"], self.bias.gain, float(self.bias.P[1, 1]), self.schedule["x_var"])
            self.landing = {"V_f": V, "n": 0, "sum": 0.0, "open": True}
            self.schedule, self.holding = None, True
            self.previous = (x, 0.0, V)
        if self.landing is not None and self.landing["open"] and V == self.landing["V_f"]:
            self.landing["n"] += 1
            self.landing["sum"] += observed
        error = abs(x - self.target_m)
        aim = self._aim(xi0, x, V)
        if self.hold_band > 0:
            if self.holding:
                self.holding = error <= self.hold_band * self.tolerance_m + HOLD_STDS * self.estimate_std_m
            else:
                self.holding = error < self.hold_band * self.tolerance_m
        if self.holding or self._wait(x, aim):
            self.plan = torch.zeros(1, T, 1, dtype=torch.float64)
            self.solve_ms.append(1e3 * (time.perf_counter() - start))
            dV = self._recentre(x) if self.holding else 0.0
            if dV and self.landing is not None:
                self.landing["open"] = False        # what follows a re-centring is not the landing
            return dV
        if not self.started and self._below_onset(xi0, x, V):
            self.solve_ms.append(1e3 * (time.perf_counter() - start))
            return min(self.plant_dv_max_V, self.v_max_V - V)
        # the model's travel that the plant turns into the remaining distance (1 + g) Δ
        model_target = x + (aim - x) / (1.0 + self.gain_error)
        self.cost = self._cost(model_target)
        tolerance = self.tolerance_m / (1.0 + self.gain_error)
        # short of the target (x above it) the full ramp up, past it (a pull back) the full ramp
        # down is the fastest way there; while even that does not bring the coin within the
        # tolerance inside the horizon it is applied without solving (module docstring)
        fastest = ramp if x > model_target else -ramp
        out_of_reach = stalled = False
        if abs(x - model_target) > tolerance:
            reach = self._roll(xi0, fastest)[0, :, 0] * X_UNIT_M
            out_of_reach = bool((reach - model_target).abs().min() > tolerance and
                                bool(((reach - model_target) * (x - model_target) > 0).all()))
        if out_of_reach:
            self.plan = fastest
        else:
            warm = mpc.shift(self.plan) if self.plan is not None else fastest
            solver = self.dynamics.solve if self.native else functools.partial(mpc.solve, self.dynamics)
            sol = solver(self.cost, xi0.repeat(3, 1), torch.cat([warm, ramp, -ramp]), -1.0, 1.0,
                         iterations=cfg.iterations)
            best = int(sol.cost.argmin())
            self.plan = sol.u[best].unsqueeze(0)
            # a plan that leaves V where it is and the coin standing, short of the target or
            # past it: the motion more voltage would bring comes too late in the horizon to pay
            # for its ΔV (f-memory: the tip must first reload its friction), and the next plan
            # would say the same (module docstring, "Stalls")
            # outside the hold band, not only outside the tolerance: between the two the policy
            # neither holds (nor re-centres) nor moves, and a coin that stands there on a biased
            # estimate stays outside for good (tests/control/test_mpc.py::
            # test_a_coin_standing_outside_the_hold_band_creeps_even_inside_the_tolerance)
            band = self.hold_band * tolerance if self.hold_band > 0 else tolerance
            stalled = (UNSTALL and abs(x - model_target) > band and float(self.plan[0, 0, 0]) == 0.0
                       and float(sol.x[best, 1, 1]) == 0.0)
        self.solve_ms.append(1e3 * (time.perf_counter() - start))
        dV = float(self.plan[0, 0, 0]) * self.dv_max_V
        creep = min(cfg.creep_V, self.dv_max_V)
        if self.approach_m > 0 and not self._at_reach(xi0, x, V):
            # slow down near the target: the coin's coast after V stops rising grows with its
            # speed, which f_a (quasi-static tip) does not model
            limit = max(creep, self.dv_max_V * abs(x - self.target_m) / self.approach_m)
            dV = max(-limit, min(limit, dV))
        if stalled:
            dV = creep if x > model_target else -creep
        if self.hold_band > 0 and 0 < abs(dV) < creep:
            # outside the hold region a step too small to drag the coin (its slip rate under
            # the friction's regularisation, docs/control.md) would only stall: creep instead
            dV = math.copysign(creep, dV)
        return dV

