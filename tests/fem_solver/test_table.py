"""The DEA on the table (scene part ``[table]``): the penalty's pressure law on a flat punch,
the friction's direction, the force balance with the clamp, and that only a scene with the
part assembles it. Tiny meshes; every expected value comes from outside the code under
test (a pressure times an area, Coulomb's law, the DEA's weight)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from mpi4py import MPI

from deapull import scene as scenes
from deapull.fem_solver import compat
from deapull.fem_solver.problem import DEAProblem
from deapull.fem_solver.simulation import mesh_scene
from deapull.fem_solver.stepping import Stepper
from deapull.meshing.layout import layout

#: the DEA alone, 2 mm above a table at y = 0
TABLE = ("dea.clamp_gap_m=0.002", "table.height_m=0.0", "table.penalty_N_m3=1e9", "table.mu_g=0.5",
         "mesh.n_length=4", "mesh.n_width=2")


def _problem(tmp_path, *overrides, name="free_bending"):
    sc = scenes.load(name, overrides=overrides)
    msh, _ = mesh_scene(sc, tmp_path / "mesh", MPI.COMM_WORLD)
    mesh, ct, ft = compat.read_mesh(msh)
    return sc, DEAProblem(sc, mesh, ct, ft)


def _move(problem, depth_m, slip_m=(0.0, 0.0), dt=1.0):
    """Translate the DEA rigidly so that its flat underside is ``depth_m`` below the table's
    top, having slid by ``slip_m`` = (Δx, Δz) since the last accepted state."""
    lay, tb = layout(problem.scene), problem.scene.table
    _, dofs = compat.displacement_dofs(problem.W, problem.has_parts)
    problem.w.x.array[:] = 0.0
    problem.w.x.array[dofs[:, 1]] = tb.height_m - lay.y_bottom_m - depth_m
    problem.w_old.x.array[:] = problem.w.x.array
    problem.w.x.array[dofs[:, 0]] += slip_m[0]
    problem.w.x.array[dofs[:, 2]] += slip_m[1]
    problem.set_load(0.0, 0.0, dt)


@pytest.mark.parametrize("cell", ["hexahedron", "tetrahedron"])   # tetrahedra: Gauss (no Lobatto on triangles)
@pytest.mark.parametrize("sym", ["none", "half_z"])
def test_flat_punch_pressure_is_penalty_times_depth_times_area(tmp_path, sym, cell):
    sc, p = _problem(tmp_path, *TABLE, f"mesh.symmetry='{sym}'", f"mesh.cell='{cell}'")
    depth = 3e-6
    _move(p, depth)
    Rx, Ry = p.table_reaction()
    assert Ry == pytest.approx(sc.table.penalty_N_m3 * depth * sc.dea.length_m * sc.dea.width_m, rel=1e-9)
    assert abs(Rx) < 1e-12 * Ry
    assert p.table_penetration() == pytest.approx(depth, rel=1e-9)
    _move(p, -1e-6)                                    # lifted 1 µm: nothing touches
    assert p.table_reaction() == (0.0, 0.0) and p.table_penetration() == 0.0


@pytest.mark.parametrize("slip, sign_x", [((2e-3, 0.0), -1.0), ((-2e-3, 0.0), 1.0), ((0.0, 2e-3), 0.0)])
def test_table_friction_opposes_the_slip_at_mu_g_times_the_normal_force(tmp_path, slip, sign_x):
    # sliding 2 mm in 1 s, 200x the regularisation eps_v = 1e-5 m/s: Coulomb's |t| = mu_g p_n to 1e-5
    sc, p = _problem(tmp_path, *TABLE, "mesh.symmetry='none'")
    _move(p, 3e-6, slip_m=slip, dt=1.0)
    Rx, Ry = p.table_reaction()
    assert Ry > 0
    if sign_x:
        assert Rx == pytest.approx(sign_x * sc.table.mu_g * Ry, rel=1e-4)
    else:
        assert abs(Rx) < 1e-12 * Ry                    # slip along z pushes nothing along x


def test_the_table_carries_what_the_clamp_does_not(tmp_path):
    """The DEA sags onto the table under gravity (placement, V = 0): clamp and table together
    carry its weight, and the table a good part of it."""
    sc, p = _problem(tmp_path, "dea.clamp_gap_m=0.001", "table.height_m=0.0", "table.penalty_N_m3=1e10",
                     "mesh.n_length=8", "mesh.n_width=2", "load.voltage_max_V=0.0")
    Stepper(p, progress=False).start(0.0)
    rx, ry = p.clamp_reaction()
    Rx, Ry = p.table_reaction()
    W = sc.dea.density_kg_m3 * sc.gravity_m_s2 * sc.dea.length_m * sc.dea.width_m * (
        sc.dea.active_thickness_m + sc.dea.passive_thickness_m)
    assert Ry > 0.2 * W
    assert ry + Ry == pytest.approx(W, rel=1e-4)
    assert abs(rx + Rx) < 1e-4 * W
    assert p.table_penetration() < 1e-5


def test_only_a_scene_with_a_table_assembles_it(tmp_path):
    _, p = _problem(tmp_path, "mesh.n_length=4", "mesh.n_width=2")
    assert p.table is None and p.table_reaction() == (0.0, 0.0) and p.table_penetration() == 0.0
    _, q = _problem(tmp_path, *TABLE)
    assert q.table is not None


def test_bad_table_input_names_the_key(tmp_path):
    with pytest.raises(scenes.SceneError, match=r"table\.mu_g = -0\.1"):
        scenes.load("coin_pull", overrides=("table.mu_g=-0.1",))
    with pytest.raises(scenes.SceneError, match=r"table\.height_m = 0\.01: must be below"):
        scenes.load("coin_pull", overrides=("table.height_m=0.01",))
    with pytest.raises(scenes.SceneError, match=r"table\.nope: unknown key"):
        scenes.load("coin_pull", overrides=("table.nope=1",))
    assert not math.isnan(scenes.load("coin_pull").table.penalty_N_m3)
    assert np.isfinite(scenes.load("coin_pull").table.height_m)


def test_the_old_penalty_key_names_its_replacement():
    with pytest.raises(scenes.SceneError, match=r"contact\.penalty_scale: no longer a key; give contact\.penalty_N_m3"):
        scenes.load("coin_pull", overrides=("contact.penalty_scale=10",))
