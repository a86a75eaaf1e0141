"""State filters for noisy observations of the coin's position (``--policy mpc+kf,pd+kf``).

The env observes x̃ = x + n, n ~ N(0, σ²), σ the env's ``noise_std_m`` (the sensor's
specification, known to the controller). A policy that acts on x̃ itself passes the noise
straight into its action; these filters average it out with a model of the motion.

* :class:`ModelKalman` — the MPC's filter: a scalar Kalman filter on x whose prediction is
  the controller's own model (f_a with the current φ, from the previous estimate and the
  two applied voltages); its process noise q (m per step) stands for the model's error.
  The velocity estimate is the model's prediction.
* :class:`BiasKalman` — the offset-free MPC's estimator: a two-state Kalman filter on
  (x, g), g the model's gain error, x' = x + (1 + g) Δ with Δ the model's predicted step.
  A model that is wrong by a constant factor while the coin slides (f_a trained on other
  coins, or on the surrogate's data while the plant is the FEM) shows in the innovations
  of every moving step; g takes them up, and the MPC plans the corrected travel
  (:mod:`deapull.control.mpc_policy`). While the coin is stuck (Δ = 0) g is not
  observable and stays; x is then the average of the observations.
* :class:`ConstantVelocityKalman` — the PD's filter (it has no model): a two-state
  Kalman filter on (x, u) with a constant-velocity prediction and white acceleration
  noise of std ``accel_std`` (m/s²), i.e. an alpha–beta filter with the optimal,
  time-varying gains.

With σ = 0 both return the observation unchanged. For a random-walk model error q ≪ σ the
steady-state gain is ≈ q/σ and the estimate's std ≈ √(qσ): with q = 1 µm, ~14 µm at
σ = 0.1 mm and ~45 µm at σ = 1 mm (against the tolerance of 10 µm).

:func:`settle_bound` and :func:`observations_for` are the information bound on settling under
noise: what no controller, this MPC included, can beat with a model that knows the plant's
travel only up to its scale (docs/control.md, "What noise allows").
"""
from __future__ import annotations

import collections
import math
from dataclasses import dataclass

import numpy as np

from deapull.errors import InputError

FILTERS = ("none", "kf")
#: the release's slope may change by its prior std over this many volts of fall, about the FEM's dead band
#: of a release (~20 V, :class:`BiasKalman`)
RELEASE_SPAN_V = 30.0
#: a release step's own slide is uncertain by RELEASE_JUMP × the slope's prior std × its fall: in a
#: creeping release the FEM's coin slips in bursts, 0 to ~30 µm per V from step to step
#: (docs/control.md, the multi-setpoint task)
RELEASE_JUMP = 3.0
#: what an MPC plans from (:class:`EstimatorConfig`)
ESTIMATORS = ("bias", "kf", "none")


@dataclass(frozen=True)
class EstimatorConfig:
    """The MPC's state estimate (``[mpc.estimator]``).

    Attributes
    ----------
    kind : {"bias", "kf", "none"}
        ``bias`` (default): :class:`BiasKalman`, the position and f_a's gain error g at every
        noise level (offset-free tracking); ``kf``: :class:`ModelKalman`, the position alone;
        ``none``: the observation itself.
    process_std_m, process_fraction : float
        q₀, the model's one-step position error at rest (m), and κ, its error per moving step as
        a fraction of the predicted step (for ``bias``: the part g does not explain).
    innovation_window : int
        :class:`BiasKalman`'s innovation check over this many steps (0: off): an estimate that
        lags the observations by more than the filter's own std allows is let go to follow them.
    release_slope_m : float
        :class:`BiasKalman`'s release (the prior std of the release's slope, m per V; 0: off): while V
        falls the coin slides back by a slope the filter learns from the observations, not by f_a's step.
    hold_coast : bool
        :class:`BiasKalman`'s step at a held voltage: ``True`` (default) moves the estimate by f_a's
        step, as on every step; ``False`` keeps it where it is and adds that step as variance, so that the
        observations decide whether the coin coasted. For an f_a trained on rising voltages only (its
        card's known limits): the quasi-static DEA's tip stands at a held V, and the FEM's coin stops
        within two steps, where an f-memory f_a keeps its coin coasting ~20 µm (docs/control.md).
    """

    kind: str = "bias"
    process_std_m: float = 1e-6
    process_fraction: float = 0.2
    innovation_window: int = 0
    release_slope_m: float = 0.0
    hold_coast: bool = True

    def __post_init__(self):
        if self.kind not in ESTIMATORS:
            raise InputError(f"mpc.estimator.kind = {self.kind!r}: choose one of {', '.join(ESTIMATORS)}")
        if not (math.isfinite(self.process_std_m) and self.process_std_m > 0):
            raise InputError(f"mpc.estimator.process_std_m = {self.process_std_m!r}: must be a finite number > 0")
        if not (math.isfinite(self.process_fraction) and self.process_fraction >= 0):
            raise InputError(f"mpc.estimator.process_fraction = {self.process_fraction!r}: must be a finite "
                             f"number >= 0")
        if int(self.innovation_window) != self.innovation_window or self.innovation_window < 0:
            raise InputError(f"mpc.estimator.innovation_window = {self.innovation_window!r}: must be an integer "
                             f">= 0 (steps; 0: off)")
        if not (math.isfinite(self.release_slope_m) and self.release_slope_m >= 0):
            raise InputError(f"mpc.estimator.release_slope_m = {self.release_slope_m!r}: must be a finite number "
                             f">= 0 (m per V; 0: off)")
        if not isinstance(self.hold_coast, bool):
            raise InputError(f"mpc.estimator.hold_coast = {self.hold_coast!r}: must be true or false")

    def make(self, noise_std_m: float):
        """The filter of this kind for observation noise ``noise_std_m`` (None for ``none``)."""
        if self.kind == "bias":
            return BiasKalman(noise_std_m, self.process_std_m, self.process_fraction,
                              innovation_window=int(self.innovation_window), release_slope_m=self.release_slope_m,
                              hold_coast=self.hold_coast)
        if self.kind == "kf":
            return ModelKalman(noise_std_m, self.process_std_m, self.process_fraction)
        return None


class ModelKalman:
    """Scalar Kalman filter on the position with a model's prediction (module docstring).

    Parameters
    ----------
    noise_std_m : float
        σ of the observation noise (m).
    process_std_m : float
        q₀: std of the model's one-step position error at rest (m).
    process_fraction : float
        κ: the model's error while the coin moves, as a fraction of the predicted step; the
        process variance of a step is q₀² + (κ |x_pred − x_prev|)².
    """

    def __init__(self, noise_std_m: float, process_std_m: float = 1e-6, process_fraction: float = 0.0):
        if not (noise_std_m >= 0 and process_std_m > 0 and process_fraction >= 0):
            raise ValueError(f"noise std {noise_std_m} must be >= 0, process std {process_std_m} > 0 and "
                             f"process fraction {process_fraction} >= 0")
        self.r, self.q, self.kappa = float(noise_std_m) ** 2, float(process_std_m) ** 2, float(process_fraction)
        self.x, self.P = math.nan, math.nan

    def reset(self, x_obs: float) -> float:
        """Start from the first observation (variance σ²)."""
        self.x, self.P = float(x_obs), self.r
        return self.x

    def update(self, x_pred: float, x_obs: float) -> float:
        """The estimate after the model predicted ``x_pred`` from the previous estimate and
        ``x_obs`` was observed."""
        if self.r == 0:
            self.x, self.P = float(x_obs), 0.0
            return self.x
        prior = self.P + self.q + (self.kappa * (float(x_pred) - self.x)) ** 2
        gain = prior / (prior + self.r)
        self.x = float(x_pred) + gain * (float(x_obs) - float(x_pred))
        self.P = (1 - gain) * prior
        return self.x


class BiasKalman:
    """Kalman filter on (x, g): the position and the model's gain error (module docstring).

    Parameters
    ----------
    noise_std_m : float
        σ of the observation noise (m); 0 (exact observations) is kept as a floor of 1 nm
        so that g is still learnt from the steps.
    process_std_m : float
        q₀: std of the model's one-step position error at rest (m).
    process_fraction : float
        κ: the rest of the model's error while the coin moves, as a fraction of the
        predicted step (what a constant g does not explain).
    gain_prior_std : float
        Std of g before any motion (0.3: the model's travel may be 30 % off).
    gain_drift_std : float
        Std of g's random walk per moving step (lets g follow a slowly changing error).
    gain_bounds : (float, float)
        g is kept inside (the corrected step (1 + g) Δ never reverses or explodes).
    innovation_window, innovation_stds : int, float
        A consistency check on the innovations (0: off). The innovations of a filter whose
        model is right are white with variance S = P + σ²; where the mean of the last
        ``innovation_window`` of them stands more than ``innovation_stds`` × √(S̄ / N) off 0,
        the model is wrong in a way g does not take up (on the FEM: the release, where the
        tip's model lets the coin stand while it slides back), and the filter says so by
        adding that mean's square to the position's variance: the estimate then follows the
        observations until it is consistent again. Each firing is counted in ``inflations``.
    release_slope_m : float
        The release (0: off, f_a's step is trusted on every step). f_a trained on rising voltages
        only (its card's known limits) does not know how far a falling V drags the coin back: the
        FEM's coin stands through the first ~20 V of a release, then slides back ~5-10 µm per V.
        With this set, a step in which V falls by ΔV > 0 is not f_a's: the coin moves back ρ ΔV, ρ
        (m per V) a third state with prior N(0, ``release_slope_m``²) that walks with variance
        ``release_slope_m``² ΔV / ``RELEASE_SPAN_V`` (a release may start to slide after a dead band).
        The observations learn ρ as they learn g, so the estimate follows a sliding coin without
        the lag of a random walk in position, the std says how far the release may have gone, and
        a later release of the same episode starts from the slope the first one measured. Where V
        holds or rises ρ is kept and moves nothing.
    hold_coast : bool
        False: a step in which V holds is not f_a's either (an f_a trained on rising voltages only has
        never seen one). The quasi-static DEA's tip stands, so the estimate stays where it is and f_a's
        step is added to its variance, not to its mean: the observations decide how far the coin coasted.
    """

    NOISE_FLOOR_M = 1e-9

    def __init__(self, noise_std_m: float, process_std_m: float = 1e-6, process_fraction: float = 0.05,
                 gain_prior_std: float = 0.3, gain_drift_std: float = 2e-3, gain_bounds=(-0.6, 1.5),
                 innovation_window: int = 0, innovation_stds: float = 4.0, release_slope_m: float = 0.0,
                 hold_coast: bool = True):
        if not (noise_std_m >= 0 and process_std_m > 0 and process_fraction >= 0 and gain_prior_std > 0
                and gain_drift_std >= 0 and gain_bounds[0] < 0 < gain_bounds[1] and innovation_window >= 0
                and innovation_stds > 0 and release_slope_m >= 0):
            raise ValueError(f"noise std {noise_std_m} >= 0, process std {process_std_m} > 0, process fraction "
                             f"{process_fraction} >= 0, gain prior std {gain_prior_std} > 0, drift "
                             f"{gain_drift_std} >= 0, gain bounds {gain_bounds} around 0, innovation window "
                             f"{innovation_window} >= 0, innovation stds {innovation_stds} > 0 and release "
                             f"slope {release_slope_m} >= 0 needed")
        self.window, self.window_stds = int(innovation_window), float(innovation_stds)
        self.innovations: collections.deque = collections.deque(maxlen=max(self.window, 1))
        self.inflations = 0
        self.r = max(float(noise_std_m), self.NOISE_FLOOR_M) ** 2
        self.q, self.kappa = float(process_std_m) ** 2, float(process_fraction)
        self.p_g, self.q_g, self.bounds = float(gain_prior_std) ** 2, float(gain_drift_std) ** 2, gain_bounds
        self.release_slope = float(release_slope_m)
        self.hold_coast = bool(hold_coast)
        self.s, self.P = np.array([math.nan, 0.0, 0.0]), np.zeros((3, 3))

    @property
    def x(self) -> float:
        return float(self.s[0])

    @property
    def gain(self) -> float:
        """g: the plant moves (1 + g) times the model's predicted step."""
        return float(self.s[1])

    @property
    def std_m(self) -> float:
        """Standard deviation of the position estimate (m)."""
        return math.sqrt(max(self.P[0, 0], 0.0))

    def reset(self, x_obs: float, gain: float = 0.0, gain_var: float | None = None,
              x_var: float | None = None) -> float:
        """Start from the position ``x_obs`` (the first observation; variance σ², or ``x_var``) and
        g = ``gain`` with variance ``gain_var`` (default: 0 with the prior's; what an earlier episode
        learnt, :class:`~deapull.control.mpc_policy.MPCPolicy`'s ``learn``)."""
        self.s = np.array([float(x_obs), float(gain), 0.0])
        self.P = np.diag([self.r if x_var is None else float(x_var),
                          self.p_g if gain_var is None else max(float(gain_var), self.q_g), self.release_slope ** 2])
        self.innovations.clear()
        return self.x

    def update(self, step_m: float, x_obs: float, held: bool = False, fall_V: float = 0.0,
               hold_V: bool = False) -> float:
        """The position estimate after the model predicted the step ``step_m`` (m, from the
        previous estimate) and ``x_obs`` was observed. ``held``: the coin stood before the step
        and the model predicts no motion (V held, or crept inside the model's dead band); static
        friction holds the coin, so the step adds no process noise and the observations average
        down as σ/√n. ``fall_V``: how far V fell in this step (V); with ``release_slope_m`` set, such a
        step is the release's (the class docstring), not the model's. ``hold_V``: V did not change in
        this step; without ``hold_coast`` the model's step is then variance, not motion (the class docstring)."""
        if self.release_slope > 0 and fall_V > 0:
            f = float(fall_V)
            return self._correct(np.array([[1.0, 0.0, f], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
                                 np.diag([self.q + (RELEASE_JUMP * self.release_slope * f) ** 2, 0.0,
                                          self.release_slope ** 2 * f / RELEASE_SPAN_V]), x_obs)
        d = float(step_m)
        if hold_V and not self.hold_coast and d != 0.0:
            return self._correct(np.eye(3), np.diag([self.q + d * d, 0.0, 0.0]), x_obs)
        moving = d != 0.0
        q = 0.0 if held and not moving else self.q
        return self._correct(np.array([[1.0, d, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
                             np.diag([q + (self.kappa * d) ** 2, self.q_g if moving else 0.0, 0.0]), x_obs,
                             step=d)

    def _correct(self, F, Q, x_obs: float, step: float = 0.0) -> float:
        """Predict with F (plus the model's step (1 + g) ``step`` on x) and process noise Q, then
        correct with the observation ``x_obs``; the position estimate."""
        s = F @ self.s
        s[0] += step
        P = F @ self.P @ F.T + Q
        if self.window:
            self.innovations.append((float(x_obs) - s[0], P[0, 0] + self.r))
            if len(self.innovations) == self.window:
                mean = sum(v for v, _ in self.innovations) / self.window
                spread = sum(S for _, S in self.innovations) / self.window
                if mean * mean > self.window_stds ** 2 * spread / self.window:
                    P[0, 0] += mean * mean
                    self.innovations.clear()
                    self.inflations += 1
        gain = P[:, 0] / (P[0, 0] + self.r)
        self.s = s + gain * (float(x_obs) - s[0])
        self.P = P - np.outer(gain, P[0, :])
        self.s[1] = float(np.clip(self.s[1], *self.bounds))
        return self.x


class ConstantVelocityKalman:
    """Kalman filter on (x, u) with x' = x + Δt u, u' = u + Δt a, a white (module docstring).

    Parameters
    ----------
    noise_std_m : float
        σ of the observation noise (m).
    dt : float
        Step (s).
    accel_std : float
        Std of the unmodelled acceleration (m/s²).
    """

    def __init__(self, noise_std_m: float, dt: float, accel_std: float = 0.05):
        if not (noise_std_m >= 0 and dt > 0 and accel_std > 0):
            raise ValueError(f"noise std {noise_std_m} >= 0, dt {dt} > 0 and accel std {accel_std} > 0 needed")
        self.r, self.dt = float(noise_std_m) ** 2, float(dt)
        self.F = np.array([[1.0, dt], [0.0, 1.0]])
        G = np.array([[0.5 * dt * dt], [dt]])
        self.Q = (G @ G.T) * accel_std ** 2
        self.s, self.P = np.zeros(2), np.zeros((2, 2))

    def reset(self, x_obs: float) -> float:
        """Start from the first observation at rest (the env starts the coin at rest)."""
        self.s = np.array([float(x_obs), 0.0])
        self.P = np.diag([self.r, 0.0])
        return float(self.s[0])

    def update(self, x_obs: float) -> float:
        """Predict one step, correct with ``x_obs``; the position estimate (m)."""
        if self.r == 0:
            self.s = np.array([float(x_obs), (float(x_obs) - self.s[0]) / self.dt])
            return float(self.s[0])
        s = self.F @ self.s
        P = self.F @ self.P @ self.F.T + self.Q
        gain = P[:, 0] / (P[0, 0] + self.r)
        self.s = s + gain * (float(x_obs) - s[0])
        self.P = P - np.outer(gain, P[0, :])
        return float(self.s[0])


def settle_bound(noise_std_m: float, tolerance_m: float, observations: float, prior_observations: float = 0.0) -> float:
    """The most probable that a coin stopped after ``observations`` noisy observations ends
    inside ±``tolerance_m`` of its target: erf(w √(N + N₀) / (σ √2)).

    The controller knows the plant's travel only up to its scale: x_i = (1 + g) m_i with the
    model's m_i (the coin's φ within the family prior, f_a's error), and |m_i| ≤ |m_N| on the
    way to the final position x_N. N observations x̃_i = x_i + n_i, n_i ~ N(0, σ²), then carry
    the Fisher information Σ (m_i / m_N)² / σ² ≤ N / σ² on x_N: every observation on the way is
    worth at most one at the final position. So the final position is known to no better than
    δ = σ / √(N + N₀) (Cramér–Rao; N₀ = (σ / s₀)² what a prior of std s₀ on x_N adds), and a
    coin stopped on that knowledge lands inside the window with probability at most
    P(|N(0, δ²)| < w) = erf(w / (δ √2)), the window centred on the estimate at best.

    σ = 0 gives 1. At σ = 0.1 mm, w = 10 µm: 0.68 in 100 observations (10 of 10 episodes
    with probability 0.68¹⁰ = 2 %), 0.95 in 384; at σ = 1 mm, 0.08 in 100.
    """
    if not (noise_std_m >= 0 and tolerance_m > 0 and observations >= 0 and prior_observations >= 0):
        raise ValueError(f"noise std {noise_std_m} >= 0, tolerance {tolerance_m} > 0, observations {observations} "
                         f">= 0 and prior observations {prior_observations} >= 0 needed")
    if noise_std_m == 0:
        return 1.0
    n = observations + prior_observations
    return math.erf(tolerance_m * math.sqrt(n) / (noise_std_m * math.sqrt(2.0)))


def observations_for(noise_std_m: float, tolerance_m: float, probability: float) -> float:
    """The fewest observations N with :func:`settle_bound` ≥ ``probability`` (no prior):
    N = 2 (σ erf⁻¹(p) / w)²; 0 at σ = 0."""
    if not (noise_std_m >= 0 and tolerance_m > 0 and 0 < probability < 1):
        raise ValueError(f"noise std {noise_std_m} >= 0, tolerance {tolerance_m} > 0 and probability {probability} "
                         f"in (0, 1) needed")
    from scipy.special import erfinv   # lazy: only the bound needs scipy here
    return 2.0 * (noise_std_m * float(erfinv(probability)) / tolerance_m) ** 2
