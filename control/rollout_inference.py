"""Online inference of φ from the whole episode's rollout (output error): ``mpc.inference.loss = "rollout"``.

The paper's Algorithm 2 (:mod:`deapull.control.inference`) fits φ to one-step predictions
x̂_{t+1}(x̃_t, ũ_t, V) from the observed position and a velocity differenced from two noisy
positions. Under observation noise σ those inputs carry the noise (errors in variables: a
bias towards a coin without inertia), and one step's prediction barely depends on φ (µm), so
at σ = 0.1 mm no field becomes identifiable in an episode (docs/control.md).

Here f_a is rolled out open loop from the coin at rest under every voltage applied so far,
and φ minimises the squared distance of that rollout to every observed position:

    L(φ) = Σ_t (x̂_t(φ; V_0..V_t) − x̃_t)² / σ̂²  (+ the prior, if any, as in ``inference``)

Noise then sits in the targets only (no errors in variables), and the rollout's position
depends on φ through everything that happened before (the onset, the slide, how far the coin
went: ∂x̂/∂log φ reaches ~0.1–1 mm instead of µm), so the Fisher information grows with the
episode. The price is the model's error: a rollout accumulates f_a's mismatch with the plant,
which φ then absorbs (φ becomes a calibration of f_a to this plant rather than the coin's
physical values; the prior and its weight σ̂ = max(noise, RMS misfit) bound how far).

Every ``every`` observations (once the coin has been seen to move) one Levenberg–Marquardt
step on log φ (the inferred fields) uses the rollout's residuals and their Jacobian by forward
differences; the rollout runs through f_a's compiled MPC dynamics where available
(f-coulomb, f-memory: one C call per rollout), else through torch.
"""
from __future__ import annotations

import math
import statistics

import numpy as np
import torch

from deapull.control import native
from deapull.control.dynamics import X_UNIT_M, CoinDynamics
from deapull.control.inference import BOUNDS, InferenceConfig
from deapull.errors import InputError
from deapull.surrogate.phi import Phi

#: forward-difference step in log φ for the rollout's Jacobian
FD_STEP = 1e-4


class RolloutInference:
    """φ from the episode's open-loop rollout (module docstring); the same interface as
    :class:`~deapull.control.inference.OnlineInference` where the MPC policy uses it
    (``reset``, ``observe``, ``update``, ``phi``, ``estimate``, ``fields``, ``moved``, ``log``,
    ``misfit_m``, ``crlb``).

    Parameters
    ----------
    model : Surrogate
        f_a (capability ``plan``).
    config : InferenceConfig
        ``fields``, ``initial``, ``prior``, ``observation_std_m``, ``motion_threshold_m``,
        ``damping``, ``max_log_step`` and ``wait_for_motion`` apply; ``optimizer`` must be
        ``lm``.
    dt, dv_max_V, v_max_V : float
        The control step (s), the plant's largest |ΔV| per step and its largest V (V).
    every : int
        Observations between updates (each update rolls out the whole episode a few times).
    """

    def __init__(self, model, config: InferenceConfig, dt: float, dv_max_V: float, v_max_V: float, every: int = 10):
        if config.optimizer != "lm":
            raise InputError(f"mpc.inference.loss = 'rollout' takes Levenberg-Marquardt steps (optimizer 'lm'), "
                             f"got {config.optimizer!r}")
        if int(every) != every or every < 1:
            raise InputError(f"rollout inference every {every!r}: must be an integer >= 1 (observations)")
        self.config, self.dt, self.every = config, float(dt), int(every)
        self.fields = tuple(config.fields) if config.fields is not None else tuple(model.phi_fields)
        unknown = [f for f in self.fields if f not in model.phi_fields or f not in BOUNDS]
        if unknown:
            raise InputError(f"cannot infer {', '.join(unknown)}: the {model.kind} model uses "
                             f"{', '.join(model.phi_fields)}")
        phi = Phi(**{f: torch.tensor(float(config.start[f]), dtype=torch.float64) for f in model.phi_fields})
        if native.available(model):
            self.dynamics = native.native_dynamics(model, phi, dt, dv_max_V, v_max_V)
        else:
            self.dynamics = CoinDynamics(model, phi, dt, dv_max_V, v_max_V)
        self.model_fields = tuple(model.phi_fields)
        self.dv_max_V = float(dv_max_V)
        self.lo = np.log([BOUNDS[f][0] for f in self.fields])
        self.hi = np.log([BOUNDS[f][1] for f in self.fields])
        self.reset()

    def reset(self) -> None:
        self.log_phi = np.log([float(self.config.start[f]) for f in self.fields])
        self.damping = self.config.damping
        self.x, self.V = [], []
        self.log, self.iteration, self.moved = [], 0, False
        self._sigma = self.config.observation_std_m

    # --- the estimate -----------------------------------------------------------------------

    def _phi_of(self, log_values) -> Phi:
        values = {f: torch.tensor(float(self.config.start[f]), dtype=torch.float64) for f in self.model_fields}
        values.update({f: torch.tensor(math.exp(float(v)), dtype=torch.float64) for f, v in zip(self.fields, log_values)})
        return Phi(**values)

    @property
    def phi(self) -> Phi:
        return self._phi_of(self.log_phi)

    def estimate(self) -> dict:
        out = {f: float(self.config.start[f]) for f in self.model_fields}
        out.update({f: math.exp(float(v)) for f, v in zip(self.fields, self.log_phi)})
        return out

    @property
    def transitions(self) -> int:
        return max(len(self.x) - 1, 0)

    # --- data and the rollout ---------------------------------------------------------------

    def observe(self, x_m: float, V_V: float) -> None:
        """The observed position x̃_t (m) under the applied voltage V_t (V)."""
        self.x.append(float(x_m))
        self.V.append(float(V_V))

    def rollout(self, log_values) -> np.ndarray:
        """x̂_1..x̂_t (m) of f_a from the coin at rest at x = 0 under V_0..V_t."""
        self.dynamics.phi = self._phi_of(log_values)
        V = np.asarray(self.V)
        nu = torch.from_numpy(np.diff(V) / self.dv_max_V).reshape(1, -1, 1)
        xi0 = self.dynamics.state(0.0, 0.0, float(V[0]))
        with torch.no_grad():
            compiled = getattr(self.dynamics, "rollout", None)
            xs = compiled(xi0, nu) if compiled is not None else self._torch_rollout(xi0, nu)
        return xs[0, 1:, 0].numpy() * X_UNIT_M

    def _torch_rollout(self, xi0, nu):
        out = [xi0]
        for k in range(nu.shape[1]):
            out.append(self.dynamics(out[-1], nu[:, k]))
        return torch.stack(out, 1)

    def _residuals(self, log_values) -> np.ndarray:
        """(x̂_t − x̃_t)/σ̂ over the episode (σ̂ fixed through one update)."""
        return (self.rollout(log_values) - np.asarray(self.x[1:])) / self._sigma

    def _sensitivity(self, log_values, base: np.ndarray, indices=None) -> np.ndarray:
        """∂x̂_t/∂log φ (m) by forward differences from the rollout ``base`` at ``log_values``, for the
        fields ``indices`` (default all)."""
        indices = range(len(self.fields)) if indices is None else indices
        S = np.empty((len(base), len(indices)))
        for j, i in enumerate(indices):
            trial = np.array(log_values, dtype=np.float64)
            trial[i] += FD_STEP
            S[:, j] = (self.rollout(trial) - base) / FD_STEP
        return S

    def _prior(self, log_values) -> tuple[np.ndarray, np.ndarray]:
        """The prior's residuals (log φ − log median)/std and their Jacobian (MAP with the data's
        residuals in units of σ̂)."""
        prior = self.config.prior or {}
        index = [i for i, f in enumerate(self.fields) if f in prior]
        centre = np.array([math.log(prior[self.fields[i]][0]) for i in index])
        std = np.array([prior[self.fields[i]][1] for i in index])
        J = np.zeros((len(index), len(self.fields)))
        J[range(len(index)), index] = 1.0 / std
        return (np.asarray(log_values)[index] - centre) / std, J

    def _loss(self, log_values) -> float:
        r = self._residuals(log_values)
        return float(r @ r + (np.sum(self._prior(log_values)[0] ** 2) if self.config.prior else 0.0))

    # --- updates ----------------------------------------------------------------------------

    def misfit_m(self) -> float:
        """RMS distance (m) of the current estimate's rollout to the observed positions."""
        if self.transitions == 0:
            return 0.0
        d = self.rollout(self.log_phi) - np.asarray(self.x[1:])
        return float(np.sqrt(np.mean(d * d)))

    def update(self, steps: int | None = None) -> dict | None:
        """One Levenberg–Marquardt step every :attr:`every` observations (``steps``: that many
        now, whatever the count)."""
        cfg = self.config
        if steps is None:
            if self.transitions == 0 or self.transitions % self.every:
                return None
            steps = cfg.updates_per_step
        if cfg.wait_for_motion and not self.moved:
            self.moved = self.transitions > 0 and bool(
                np.max(np.abs(np.asarray(self.x[1:]) - self.x[0])) > cfg.motion_threshold_m)
            if not self.moved:
                return None
        record = None
        for _ in range(steps):
            loss = self._lm_step()
            self.iteration += 1
            record = {"iteration": self.iteration, "loss": loss, "transitions": self.transitions, **self.estimate()}
            self.log.append(record)
        return record

    def _lm_step(self) -> float:
        current = np.array(self.log_phi, dtype=np.float64)
        base = self.rollout(current)
        d = base - np.asarray(self.x[1:])
        self._sigma = max(self.config.observation_std_m, float(np.sqrt(np.mean(d * d))))   # σ̂ of this update
        r, J = d / self._sigma, self._sensitivity(current, base) / self._sigma
        if self.config.prior:
            rp, Jp = self._prior(current)
            r, J = np.concatenate([r, rp]), np.vstack([J, Jp])
        loss = float(r @ r)
        H, g = J.T @ J, J.T @ r
        scale = np.diag(np.diag(H)) + 1e-12 * np.eye(len(current))
        for _ in range(30):
            try:
                step = -np.linalg.solve(H + self.damping * scale, g)
            except np.linalg.LinAlgError:
                step = np.full_like(current, np.nan)
            if np.all(np.isfinite(step)):
                step = step * min(1.0, self.config.max_log_step / max(np.max(np.abs(step)), 1e-300))
                trial = np.clip(current + step, self.lo, self.hi)
                new = self._loss(trial)
                if new < loss:
                    self.damping = max(self.damping / 3, 1e-9)
                    self.log_phi = trial
                    return new / max(self.transitions, 1)
            self.damping = min(self.damping * 4, 1e12)
            if self.damping >= 1e12:
                break
        return loss / max(self.transitions, 1)

    def _fit(self, log_values, free: list[int], steps: int = 30) -> tuple[np.ndarray, float]:
        """``log_values`` with the fields ``free`` (indices) moved by up to ``steps`` damped Gauss–Newton
        steps down the loss at the current σ̂, the others held; returns (log φ, loss)."""
        x = np.array(log_values, dtype=np.float64)
        loss, damping = self._loss(x), 1e-3
        if not free:
            return x, loss
        for _ in range(steps):
            base = self.rollout(x)
            r = (base - np.asarray(self.x[1:])) / self._sigma
            J = self._sensitivity(x, base, free) / self._sigma
            if self.config.prior:
                rp, Jp = self._prior(x)
                r, J = np.concatenate([r, rp]), np.vstack([J, Jp[:, free]])
            H, g = J.T @ J, J.T @ r
            scale = np.diag(np.diag(H)) + 1e-12 * np.eye(len(free))
            for _ in range(12):
                step = -np.linalg.solve(H + damping * scale, g)
                trial = x.copy()
                trial[free] = np.clip(x[free] + step, self.lo[free], self.hi[free])
                new = self._loss(trial)
                if new < loss:
                    gain, x, loss, damping = loss - new, trial, new, max(damping / 3, 1e-9)
                    break
                damping *= 4
            else:
                break
            if gain < 1e-3:
                break
        return x, loss

    def profile_interval(self, field: str, noise_std_m: float, level: float = 0.68,
                         step_log: float | None = None) -> tuple[float, float]:
        """The profile-likelihood interval of ``field`` (its values, not their logs) at ``level``.

        The profile P(a) is the loss with log φ_field held at a and the other fields fitted
        (:meth:`_fit`), σ̂ the larger of ``noise_std_m`` and the RMS misfit at the estimate, the
        prior included. The interval is where P − min P ≤ z², z the normal quantile of ``level``
        (Wilks). P is walked from the estimate outwards in steps of ``step_log`` (default a tenth of
        the field's prior std, or 0.01) to where it crosses that level, or to the field's bound, and
        the crossing interpolated linearly. A ridge (μ_b and μ_t moving together, which the push
        sees as one onset) bends away from the Laplace approximation's straight line; the profile
        follows it.
        """
        i = self.fields.index(field)
        free = [j for j in range(len(self.fields)) if j != i]
        self._sigma = max(noise_std_m, self.misfit_m())
        prior = (self.config.prior or {}).get(field)
        h = step_log or (0.1 * prior[1] if prior else 0.01)
        z2 = statistics.NormalDist().inv_cdf(0.5 + level / 2) ** 2
        start, best = self._fit(self.log_phi, free)
        walks = {}
        for sign in (-1.0, 1.0):
            x, points = start.copy(), [(float(start[i]), best)]
            while True:
                a = float(np.clip(points[-1][0] + sign * h, self.lo[i], self.hi[i]))
                if a == points[-1][0]:
                    break
                x[i] = a
                x, loss = self._fit(x, free)
                points.append((a, loss))
                best = min(best, loss)
                if loss - best > 2 * z2 or len(points) > 400:
                    break
            walks[sign] = points
        points = sorted(walks[-1.0][1:] + walks[1.0])
        k = min(range(len(points)), key=lambda j: points[j][1])
        edges = []
        for run in (points[k::-1], points[k:]):      # from the profile's minimum outwards, each way
            edge = run[-1][0]
            for (a0, p0), (a1, p1) in zip(run, run[1:]):
                if p1 - best > z2:
                    edge = a0 + (a1 - a0) * (z2 - (p0 - best)) / (p1 - p0)
                    break
            edges.append(edge)
        return math.exp(edges[0]), math.exp(edges[1])

    def sensitivity(self) -> np.ndarray:
        """∂x̂_t/∂log φ (t × p) of the episode's rollout at the current estimate (forward differences)."""
        return self._sensitivity(self.log_phi, self.rollout(self.log_phi))

    def crlb(self, noise_std_m: float) -> dict:
        """The Cramér–Rao bound on each inferred field's relative error from the episode's
        rollout: S = ∂x̂_t/∂log φ (forward differences), F = SᵀS/σ² (inf where F is singular)."""
        if self.transitions == 0:
            return {f: math.inf for f in self.fields}
        S = self._sensitivity(self.log_phi, self.rollout(self.log_phi))
        F = S.T @ S / noise_std_m ** 2
        eig = np.linalg.eigvalsh(F)
        if not eig.min() > 1e-12 * max(float(eig.max()), 1e-300):
            return {f: math.inf for f in self.fields}
        return dict(zip(self.fields, np.sqrt(np.clip(np.diag(np.linalg.inv(F)), 0, None)).tolist()))
