"""The one path from a scene to a running simulation: scene → mesh → problem → stepper.

::

    sim = Simulation.from_scene("coin_pull", "C3", mesh_dir="out/meshes/C3")
    records = sim.stepper().run()          # or stepper.start(); stepper.advance(V, dt) ...

:meth:`Simulation.from_scene` meshes the scene (rank 0) and reads the ``.msh`` once: the
DEA mesh for dolfinx and the coin's mesh volume, whose product with the density is the
coin's mass ``mass_kg``. The scene's layout (:func:`deapull.meshing.layout.layout`) is
computed once and shared by the mesher and the problem. ``fem_solver.run.solve_scene`` (the
CLI's ``solve`` and the sweep) and the FEM plant of ``deapull.control.plants`` both start here.
"""
from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mpi4py import MPI

from deapull import scene as scenes
from deapull.errors import InputError
from deapull.fem_solver import compat
from deapull.fem_solver.problem import DEAProblem
from deapull.fem_solver.stepping import Stepper
from deapull.meshing.build import write_mesh
from deapull.meshing.layout import Layout, layout
from deapull.scene import Scene


def mesh_scene(scene: Scene, out_dir: Path, comm) -> tuple[Path, dict]:
    """Mesh on rank 0 of ``comm``; every rank gets the path and the summary."""
    result = write_mesh(scene, out_dir) if comm.rank == 0 else None
    return comm.bcast(result, root=0)


def resolve_scene(scene: Scene | str | Path, setup: str | None = None) -> Scene:
    """A scene object from a scene, or a shipped scene's name or a TOML path with its setup."""
    if isinstance(scene, Scene):
        if setup is not None and setup != scene.setup:
            raise InputError(f"setup={setup!r} given for scene {scene.scene.name!r}, which is already resolved "
                             f"at setup {scene.setup!r}: pass the scene's name to choose a setup")
        return scene
    return scenes.load(scene, setup=setup)


#: scene keys the placement does not depend on (it is frictionless, with the coin at rest): left out
#: of its cache key, so that a scene's setups (C1..C8 differ in these alone) share one placement
PLACEMENT_FREE_KEYS = (("coin", "density_kg_m3"), ("coin", "mu_t"), ("coin", "mu_b"), ("table", "mu_g"))


class PlacementCache:
    """The placed state at t = 0 of one meshed scene, kept in ``folder`` for the runs that share it.

    The key is the SHA-256 of the mesh file and of the resolved scene without its ``[scene]`` and
    ``[load]`` sections and :data:`PLACEMENT_FREE_KEYS`; a state is stored per initial voltage and
    per rank of ``comm`` (``placement-<key>-<V>V-<rank>of<size>.npy``), written to a temporary file
    and renamed. :meth:`Stepper.start` takes it only as the first guess of the placement's last
    solve, so a stale or foreign state costs that solve and never a wrong placement.
    """

    def __init__(self, folder: str | Path, scene: Scene, mesh_path: Path, comm):
        self.folder, self.comm = Path(folder), comm
        d = scene.to_dict()
        d.pop("scene", None), d.pop("load", None)
        for section, key in PLACEMENT_FREE_KEYS:
            if section in d:
                d[section].pop(key, None)
        digest = hashlib.sha256(json.dumps(d, sort_keys=True, default=str).encode())
        digest.update(Path(mesh_path).read_bytes())
        self.key = digest.hexdigest()[:16]

    def _path(self, V: float) -> Path:
        return self.folder / f"placement-{self.key}-{V:.6g}V-{self.comm.rank}of{self.comm.size}.npy"

    def load(self, V: float, size: int):
        """This rank's stored state at initial voltage ``V`` (an array of ``size`` values), or None
        on every rank unless every rank has one."""
        path = self._path(V)
        try:
            state = np.load(path) if path.is_file() else None
        except (OSError, ValueError):
            state = None
        have = state is not None and state.shape == (size,) and bool(np.isfinite(state).all())
        return state if self.comm.allreduce(have, op=MPI.LAND) else None

    def save(self, V: float, state: np.ndarray) -> None:
        """Store this rank's ``state`` at initial voltage ``V`` (atomically)."""
        path = self._path(V)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        with open(tmp, "wb") as f:
            np.save(f, np.asarray(state))
        os.replace(tmp, path)


@dataclass
class Simulation:
    """A meshed scene, ready to step.

    Attributes
    ----------
    scene : the resolved scene
    mesh_path, mesh_summary : the ``.msh`` file and the mesher's summary of it
    mesh, cell_tags, facet_tags : the DEA's dolfinx mesh and its tags
    mass_kg : the coin's mass, its mesh volume × ``coin.density_kg_m3`` (None without a coin)
    comm : the communicator the mesh is distributed over
    """
    scene: Scene
    mesh_path: Path
    mesh_summary: dict
    mesh: object
    cell_tags: object
    facet_tags: object
    mass_kg: float | None
    comm: object

    @classmethod
    def from_scene(cls, scene: Scene | str | Path, setup: str | None = None, *, mesh_dir: str | Path,
                   comm=MPI.COMM_WORLD) -> "Simulation":
        """Mesh ``scene`` (at ``setup`` when given by name) into ``mesh_dir`` and read it once."""
        scene = resolve_scene(scene, setup)
        mesh_path, summary = mesh_scene(scene, Path(mesh_dir), comm)
        read = compat.read_scene_mesh(mesh_path, comm)
        mass_kg = read.volumes_m3["coin"] * scene.coin.density_kg_m3 if scene.coin is not None else None
        return cls(scene=scene, mesh_path=mesh_path, mesh_summary=summary, mesh=read.mesh,
                   cell_tags=read.cell_tags, facet_tags=read.facet_tags, mass_kg=mass_kg, comm=comm)

    @property
    def layout(self) -> Layout:
        """Where everything sits (:class:`deapull.meshing.layout.Layout`; the one the mesh was built on)."""
        return layout(self.scene)

    def problem(self) -> DEAProblem:
        """A fresh problem on the mesh (the state at rest)."""
        return DEAProblem(self.scene, self.mesh, self.cell_tags, self.facet_tags)

    def stepper(self, problem: DEAProblem | None = None, progress: bool = True, on_step=None,
                placement_cache: str | Path | None = None) -> Stepper:
        """A stepper on ``problem`` (default: a fresh one) with the coin's mass; with
        ``placement_cache`` (a folder) it reuses and keeps the placement there (:class:`PlacementCache`)."""
        cache = None if placement_cache is None else PlacementCache(placement_cache, self.scene, self.mesh_path,
                                                                    self.comm)
        return Stepper(problem or self.problem(), self.mass_kg, progress=progress, on_step=on_step,
                       placement_cache=cache)
