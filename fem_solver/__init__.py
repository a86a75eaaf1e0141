"""FEM stage (dolfinx 0.5.2): a scene → a time-stepped, coin-coupled solve → a dataset.

The one path from a scene to a running simulation is :meth:`Simulation.from_scene` (mesh,
problem, stepper; :mod:`~deapull.fem_solver.simulation`); :func:`solve_scene` runs it over the
scene's protocol and writes the dataset (:mod:`~deapull.fem_solver.run`). Below them:
:class:`DEAProblem` (:mod:`~deapull.fem_solver.problem`, with :mod:`~.materials`,
:mod:`~.electro`, :mod:`~.contact`), :class:`Stepper` (:mod:`~deapull.fem_solver.stepping`), the
coin's Coulomb step (:mod:`~deapull.fem_solver.coin`) and every dolfinx-version-specific call
(:mod:`~deapull.fem_solver.compat`).
"""
from deapull.fem_solver.coin import CoinState, coulomb_step, force_balance_residual
from deapull.fem_solver.compat import MeshFileError, SceneMesh, read_mesh, read_scene_mesh
from deapull.fem_solver.problem import DEAProblem, SolveResult
from deapull.fem_solver.run import solve_scene
from deapull.fem_solver.simulation import Simulation, mesh_scene
from deapull.fem_solver.stepping import SolveFailed, StepRecord, Stepper, scene_protocol

__all__ = ["CoinState", "DEAProblem", "MeshFileError", "SceneMesh", "Simulation", "SolveFailed", "SolveResult",
           "StepRecord", "Stepper", "coulomb_step", "force_balance_residual", "mesh_scene", "read_mesh",
           "read_scene_mesh", "scene_protocol", "solve_scene"]
