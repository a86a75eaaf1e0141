"""Plants: what the controller acts on, behind one protocol.

A plant holds the true coin. ``reset()`` places the DEA on the coin at rest (x = 0, u = 0)
at 0 V; ``step(V)`` applies one step of Δt = :data:`DT_S`, the voltage going
linearly from the current value to ``V`` (the FEM's ``advance(V, dt)``; the surrogates'
action a = (V_{t+1}, Δt) is the same thing), and returns the true state (x, u) in m and
m/s as a float64 array. Observation noise is not the plant's business: the env adds it
(:mod:`deapull.control.env`).

* :class:`SurrogatePlant` — a trained surrogate simulating one coin φ (the paper's f_{s,1}
  and f_{s,2}: f trained on C1 / C2 with that setup's φ).
* :class:`FEMPlant` — the FEM of a scene stepped online (``Stepper.start()`` /
  ``advance(V, dt)``); dolfinx is imported only when one is built.
"""
from __future__ import annotations

import copy
import math
import tempfile
import time
from pathlib import Path
from typing import Protocol

import numpy as np
import torch

from deapull.errors import InputError
from deapull.surrogate.phi import Phi

#: the control step of the paper (s): fixed, not chosen by the policy
DT_S = 1e-3


class PlantFailed(RuntimeError):
    """The plant could not take the step (e.g. the FEM solve failed); the message says why."""


class Plant(Protocol):
    """The protocol every plant follows.

    Attributes
    ----------
    name : str
        E.g. ``surrogate:C1`` or ``fem:C1``.
    dt : float
        Step length Δt (s).
    t : float
        Time of the current state (s), 0 after ``reset``.
    V : float
        Voltage of the current state (V).
    truth : Phi
        The true coin's φ (for reporting; a controller must not read it).
    """

    name: str
    dt: float
    t: float
    V: float
    truth: Phi

    def reset(self, seed: int | None = None) -> np.ndarray:
        """The coin at rest, x = 0, under the DEA at 0 V; returns (x, u). ``seed`` is for
        plants with randomness of their own (the present ones are deterministic)."""

    def step(self, V: float) -> np.ndarray:
        """One step of Δt to the voltage ``V``; returns the true (x, u) (m, m/s)."""


def _check_voltage(V: float, who: str) -> float:
    V = float(V)
    if not (math.isfinite(V) and V >= 0):
        raise InputError(f"{who}: voltage must be finite and >= 0 V, got {V!r}")
    return V


class SurrogatePlant:
    """A trained surrogate as the plant, simulating the coin ``phi``.

    Parameters
    ----------
    model : deapull.surrogate.models.Surrogate
        Trained model (e.g. from :func:`deapull.surrogate.store.load`); the plant steps a
        float64 copy of it without gradients.
    phi : Phi or None
        The true coin (``model.phi_of(data)`` of the setup it simulates; None for the black
        boxes).
    name : str
    dt : float
        Step length (s).
    """

    def __init__(self, model, phi: Phi | None, name: str = "surrogate", dt: float = DT_S):
        self.model = copy.deepcopy(model).double().eval()
        self.truth = model.check_phi(phi)
        self._phi = None if phi is None else phi.to(dtype=torch.float64)
        self.name, self.dt = name, float(dt)
        self.t, self.V = 0.0, 0.0
        self._s = self._memory = None

    def _action(self, V: float) -> torch.Tensor:
        return torch.tensor([[V, self.dt]], dtype=torch.float64)

    @torch.no_grad()
    def reset(self, seed: int | None = None) -> np.ndarray:
        self._s = torch.zeros(1, 2, dtype=torch.float64)
        self._memory = self.model.init_memory(self._s, self._action(0.0))
        self.t, self.V = 0.0, 0.0
        return self.state

    @torch.no_grad()
    def step(self, V: float) -> np.ndarray:
        if self._s is None:
            raise RuntimeError(f"{self.name}: call reset() before step()")
        V = _check_voltage(V, self.name)
        self._s, _, self._memory = self.model.step(self._s, self._action(V), self._memory, self._phi)
        self.t, self.V = self.t + self.dt, V
        return self.state

    @property
    def state(self) -> np.ndarray:
        """The current (x, u) (m, m/s), float64."""
        return self._s[0].numpy().astype(np.float64)


class FEMPlant:
    """The FEM of ``scene`` as the plant, stepped online (serial, one process).

    Parameters
    ----------
    scene : deapull.scene.Scene
        A scene with a coin (e.g. ``coin_pull`` at setup C1); its ``time``, ``solver`` and
        ``mesh`` keys apply (cut-backs inside a step of Δt included).
    work_dir : str or pathlib.Path, optional
        Where the mesh is written (default: a temporary folder kept as long as the plant).
    name : str
    dt : float
        Step length (s).

    The mesh and the coin's mass are made once; every ``reset`` builds a fresh problem and
    :class:`~deapull.fem_solver.stepping.Stepper` and places the DEA on the coin at 0 V
    (``start(0)``; from the second reset on, from the first one's placement, kept in ``work_dir``).
    A step that the FEM cannot solve raises :class:`PlantFailed`. The
    episode's accepted FEM records are kept (:attr:`records`), and :meth:`save` writes them
    as a dataset of the FEM's contract: an FEM run under the controller's voltages, which
    the surrogates train on like any other run (``deapull control --set control.save_fem_runs=DIR``).
    """

    def __init__(self, scene, work_dir: str | Path | None = None, name: str = "fem", dt: float = DT_S):
        if scene.coin is None:
            raise InputError(f"scene {scene.scene.name!r} has no [coin]: the FEM plant needs one")
        from mpi4py import MPI  # lazy: dolfinx and MPI load only when a FEM plant is built

        from deapull.fem_solver.simulation import Simulation  # lazy: as above
        self.scene, self.name, self.dt = scene, name, float(dt)
        self.comm = MPI.COMM_SELF
        if work_dir is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="deapull-fem-plant-")
            work_dir = self._tmp.name
        self._work = Path(work_dir)
        self.simulation = Simulation.from_scene(scene, mesh_dir=self._work / "mesh", comm=self.comm)
        self.mesh_summary, self.mass_kg = self.simulation.mesh_summary, self.simulation.mass_kg
        self.truth = Phi(mass_kg=self.mass_kg, mu_b=scene.coin.mu_b, mu_t=scene.coin.mu_t)
        self.stepper = self.problem = None
        self.t, self.V = 0.0, 0.0
        self.records: list = []
        self._started = 0.0

    def reset(self, seed: int | None = None) -> np.ndarray:
        from deapull.fem_solver.stepping import SolveFailed  # lazy: dolfinx loads only with a FEM plant
        self.problem = self.simulation.problem()
        self.stepper = self.simulation.stepper(self.problem, progress=False, placement_cache=self._work / "placements")
        self.records, self._started = [], time.perf_counter()
        try:
            return self._keep(self.stepper.start(0.0))
        except SolveFailed as err:
            raise PlantFailed(f"{self.name}: placement failed: {err}") from err

    def step(self, V: float) -> np.ndarray:
        from deapull.fem_solver.stepping import SolveFailed  # lazy: as in reset
        if self.stepper is None:
            raise RuntimeError(f"{self.name}: call reset() before step()")
        V = _check_voltage(V, self.name)
        try:
            return self._keep(self.stepper.advance(V, self.dt))
        except SolveFailed as err:
            raise PlantFailed(f"{self.name}: {err}") from err

    def save(self, path: str | Path, name: str) -> Path:
        """The episode so far as a dataset at ``path`` (run name ``name``; the attributes say
        the voltages came from a controller)."""
        from deapull.fem_solver.run import write_run  # lazy: as in reset
        if len(self.records) < 2:
            raise RuntimeError(f"{self.name}: no episode to save (reset and step first)")
        return write_run(path, self.simulation, self.problem, self.stepper, self.records,
                         time.perf_counter() - self._started, name, protocol="closed loop (deapull control)")

    def _keep(self, record) -> np.ndarray:
        self.records.append(record)
        self.t, self.V = record.t, record.V
        return np.array([record.x, record.u], dtype=np.float64)


def ramp_reach_m(plant, dv_max_V: float, v_max_V: float, steps: int) -> float:
    """The furthest position (m, most negative x) the plant's coin reaches under the fastest push
    a policy can give: V rising by ``dv_max_V`` per step to ``v_max_V`` and held, for ``steps``
    steps from rest. Voltage moves the coin toward −x only while it rises, so no policy under
    the same |ΔV| limit gets further in as many steps. Resets the plant before and after."""
    plant.reset()
    x_min, V = 0.0, 0.0
    for _ in range(int(steps)):
        V = min(V + dv_max_V, v_max_V)
        x_min = min(x_min, float(plant.step(V)[0]))
    plant.reset()
    return x_min
