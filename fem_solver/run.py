"""One scene, end to end: :class:`~deapull.fem_solver.simulation.Simulation` (mesh, problem,
stepper) → time stepping → dataset (and optional XDMF fields)."""
from __future__ import annotations

import logging
import math
import time
from pathlib import Path

from mpi4py import MPI

from deapull import dataset, provenance
from deapull.fem_solver import compat
from deapull.fem_solver.simulation import Simulation
from deapull.fem_solver.stepping import as_arrays, coin_motion, coin_travel

log = logging.getLogger(__name__)


def run_name(scene) -> str:
    """File stem of a run: the setup (C3) or the scene name."""
    return scene.setup or scene.scene.name


class FieldWriter:
    """Displacement fields for ParaView every ``every`` accepted steps (XDMF)."""

    def __init__(self, problem, path: Path, every: int):
        self.p, self.every = problem, every
        self.file = compat.xdmf_writer(problem.comm, path, problem.mesh)

    def __call__(self, index: int, t: float) -> None:
        if index % self.every == 0:
            u = self.p.w.sub(0).collapse() if self.p.has_parts else self.p.w
            u.name = "displacement"
            self.file.write_function(compat.interpolate_to_p1(u, self.p.mesh), t)

    def close(self) -> None:
        self.file.close()


#: measured bias of the coin travel from the friction regularisation ε_v (docs/fem_accuracy.md,
#: "Friction regularisation"): C3 on the shipped mesh with its 5 x 5 contact points, travel at
#: ε_v against ε_v = 1e-6 m/s
SLIP_RATE_BIAS = {1e-4: -0.036, 1e-5: -0.0017}


def slip_rate_bias(scene) -> str:
    """The dataset's statement of the ε_v bias: the measured figure for a studied ε_v."""
    eps = scene.contact.slip_rate_regularisation_m_s
    for value, bias in SLIP_RATE_BIAS.items():
        if math.isclose(eps, value, rel_tol=1e-9):
            return (f"coin travel {100 * bias:+.2f} % against eps_v = 1e-6 m/s (C3, shipped mesh, measured; "
                    "docs/fem_accuracy.md)")
    return f"not measured for eps_v = {eps:g} m/s (studied: {', '.join(f'{v:g}' for v in SLIP_RATE_BIAS)})"


def sharp_geometry_warnings(scene) -> list[str]:
    """What of the DEA-obstacle geometry has no mesh-converged contact (docs/physics.md, "Contact
    geometry"): a sharp free edge (its indentation of the rim is singular) and a circular rim (its
    curvature jumps where the edge rides onto it)."""
    obstacle = scene.coin or scene.stop
    if obstacle is None:
        return []
    out = []
    if scene.dea.free_edge_radius_m == 0:
        out.append("dea.free_edge_radius_m = 0: the DEA's sharp free edge indents the rim with a singular "
                   "stress, and the travel has no mesh-converged value; round it (0.5 mm in coin_pull)")
    if obstacle.edge_shape == "circular":
        out.append(f"{'coin' if scene.coin else 'stop'}.edge_shape = 'circular': the rim's curvature jumps where "
                   "the free edge rides onto it; 'c2' blends it")
    return out


def solve_scene(scene, out_dir, comm=MPI.COMM_WORLD, fields_every: int = 0, progress: bool = True,
                name: str | None = None) -> Path:
    """Solve one scene (one setup) and write ``out_dir/<setup or scene>.nc``.

    Raises
    ------
    fem_solver.stepping.SolveFailed
        when a step cannot be solved after the cut-backs; no dataset is written then.
    """
    out_dir = Path(out_dir)
    name = name or run_name(scene)
    start = time.perf_counter()
    sim = Simulation.from_scene(scene, mesh_dir=out_dir / "meshes" / name, comm=comm)
    mass_kg = sim.mass_kg
    problem = sim.problem()
    if comm.rank == 0:    # one mesh split over ranks: one line, not one per rank
        log.info("%s: %d dofs on %d ranks, coin mass %s", name, problem.num_dofs(), comm.size,
                 f"{mass_kg * 1e3:.4f} g" if mass_kg else "-")
        for line in sharp_geometry_warnings(sim.scene):
            log.warning("%s: %s", name, line)
    writer = FieldWriter(problem, out_dir / f"{name}_fields.xdmf", fields_every) if fields_every > 0 else None
    # the setups of a scene share the mesh and its placement (fem_solver.simulation.PlacementCache)
    stepper = sim.stepper(problem, progress=progress, on_step=writer, placement_cache=out_dir / "meshes" / "placements")
    try:
        records = stepper.run()
    finally:
        if writer is not None:
            writer.close()
    wall = time.perf_counter() - start
    path = write_run(out_dir / f"{name}.nc", sim, problem, stepper, records, wall, name)
    if comm.rank == 0:
        log.info("%s: %d points, coin travel %.3f mm, %.1f s -> %s", name, len(records),
                 coin_travel(records) * 1e3, wall, path)
    return path


def write_run(path, sim, problem, stepper, records, wall_s: float, name: str, protocol: str | None = None) -> Path:
    """Write the accepted ``records`` of a run of ``sim`` as a dataset at ``path`` (rank 0,
    atomically): the variables of the dataset contract and the attributes that say what was
    run (scene, mesh, contact, table, solver, versions). ``protocol`` names the voltage input
    when it is not the scene's own (e.g. a controller's, stepped online by the FEM plant)."""
    scene, comm, mass_kg, summary = sim.scene, problem.comm, sim.mass_kg, sim.mesh_summary
    attrs = {
        "title": f"deapull FEM run {name}",
        "scene": scene.scene.name, "setup": scene.setup, "scene_toml": scene.to_toml(),
        "coin_mass_kg": mass_kg if mass_kg is not None else "",
        "coin_mu_t": scene.coin.mu_t if scene.coin else "", "coin_mu_b": scene.coin.mu_b if scene.coin else "",
        "coin_density_kg_m3": scene.coin.density_kg_m3 if scene.coin else "",
        "contact_slip_rate_reg_m_s": scene.contact.slip_rate_regularisation_m_s if scene.coin else "",
        "contact_slip_rate_reg_bias": slip_rate_bias(scene) if scene.coin else "",
        "contact_quadrature": f"{scene.contact.quadrature_rule} degree {scene.contact.quadrature_degree}",
        "contact_penalty_N_m3": scene.contact.penalty_N_m3 if scene.has_obstacle else "",
        "contact_min_active_points": scene.contact.min_active_points if scene.has_obstacle else "",
        "contact_steps_below_min_points": stepper.steps_below_min_points,
        "table": ("height {height_m:g} m, mu_g {mu_g:g}, penalty {penalty_N_m3:.3g} N/m^3, Gauss-Lobatto degree "
                  "{quadrature_degree}".format(**vars(scene.table))) if scene.table else "none",
        "mesh_symmetry": scene.mesh.symmetry, "mesh_x_grading": scene.mesh.x_grading,
        "mesh_divisions": "x{n_length} z{n_width} active{n_active} passive{n_passive}".format(**vars(scene.mesh)),
        "solver_linear": scene.solver.linear_solver,
        "gravity_m_s2": scene.gravity_m_s2, "voltage_max_V": scene.load.voltage_max_V,
        "mesh_cells": compat.num_cells_global(sim.mesh), "mesh_dofs": problem.num_dofs(),
        "mesh_cell_type": scene.mesh.cell, "mesh_order": scene.mesh.order, "mesh_level": scene.mesh.level,
        "mesh_min_quality": summary["min_quality_detj_ratio"],
        "coin_volume_rel_error": summary.get("coin_volume_rel_error", ""),
        "mpi_ranks": comm.size, "git_commit": provenance.git_commit(), "wall_time_total_s": wall_s,
        "coin_travel_m": coin_travel(records), "coin_motion": coin_motion(records), "steps": len(records),
        "placement": stepper.placement,
        "load_protocol": protocol or scene.load.protocol,
        **provenance.package_versions(),
    }
    path = Path(path)
    if comm.rank == 0:
        dataset.write(dataset.build(as_arrays(records), attrs), path)
    comm.barrier()
    return path
