"""State filters for noisy observations of the coin's position (``--policy mpc+kf,pd+kf``).

The env observes x̃ = x + n, n ~ N(0, σ²), σ the env's ``noise_std_m`` (the sensor's
specification, known to the controller). A policy that acts on x̃ itself passes the noise
straight into its action; these filters average it out with a model of the motion.

* :class:`ModelKalman` — the MPC's filter: a scalar Kalman filter on x whose prediction is
  the controller's own model (f_a with the current φ, from the previous estimate and the
  two applied voltages); its process noise q (m per step) stands for the model's error.
  The velocity estimate is the model's prediction.
* :class:`ConstantVelocityKalman` — the PD's filter (it has no model): a two-state
  Kalman filter on (x, u) with a constant-velocity prediction and white acceleration
  noise of std ``accel_std`` (m/s²), i.e. an alpha–beta filter with the optimal,
  time-varying gains.

With σ = 0 both return the observation unchanged. For a random-walk model error q ≪ σ the
steady-state gain is ≈ q/σ and the estimate's std ≈ √(qσ): with q = 1 µm, ~14 µm at
σ = 0.1 mm and ~45 µm at σ = 1 mm (against the tolerance of 10 µm).
"""
from __future__ import annotations

import math

import numpy as np

FILTERS = ("none", "kf")


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
