"""Gmsh meshes of every shipped scene: groups, volumes, dolfinx loading (serial and MPI)."""
import json
import math

import numpy as np
import pytest

from deapull.meshing import groups
from deapull.meshing.build import write_mesh
from deapull import scene as scenes
from tests.conftest import SHARP, mpirun


@pytest.mark.parametrize("name", scenes.list_scenes())
@pytest.mark.parametrize("cell", ["hexahedron", "tetrahedron"])
def test_every_scene_meshes_with_its_groups(name, cell, tiny_scene, tmp_path):
    sc = tiny_scene(name, f"mesh.cell='{cell}'")
    path, summary = write_mesh(sc, tmp_path)
    assert path.is_file() and json.loads((tmp_path / "mesh.json").read_text()) == summary
    g = summary["groups"]
    for name_ in ("active", "passive", "clamp", "electrode_top", "electrode_bottom", "dea_contact"):
        assert g[name_]["cells"] > 0, name_
    d = sc.dea
    w = d.width_m / (2 if sc.mesh.symmetry == "half_z" else 1)       # the modelled width
    assert g["active"]["volume_m3"] == pytest.approx(d.length_m * w * d.active_thickness_m, rel=1e-9)
    corner = d.free_edge_radius_m ** 2 * (1 - math.pi / 4) * w      # the rounded free edge
    assert g["passive"]["volume_m3"] == pytest.approx(d.length_m * w * d.passive_thickness_m - corner,
                                                      rel=1e-9 if not corner else 2e-5)
    assert g["clamp"]["area_m2"] == pytest.approx(w * (d.active_thickness_m + d.passive_thickness_m))
    if sc.mesh.symmetry == "half_z":
        assert g["symmetry"]["area_m2"] == pytest.approx(d.length_m * (d.active_thickness_m + d.passive_thickness_m)
                                                         - corner / w, rel=1e-9 if not corner else 2e-5)
    else:
        assert "symmetry" not in g
    assert summary["min_quality_detj_ratio"] > 0.1
    if sc.coin is None:
        assert "coin" not in g and "coin_top" not in g
    else:
        exact = math.pi * sc.coin.radius_m ** 2 * sc.coin.height_m
        assert abs(g["coin"]["volume_m3"] / exact - 1) < 5e-3
        assert g["coin_top"]["cells"] > 0 and g["coin_bottom"]["cells"] > 0


def test_hexahedral_divisions_and_level(tiny_scene, tmp_path):
    sc = tiny_scene("free_bending", "mesh.level=1")
    _, summary = write_mesh(sc, tmp_path)
    n = 4 * 2 * 1 * 2 * 1 * 2
    assert summary["groups"]["active"]["cells"] == n and summary["groups"]["passive"]["cells"] == n


def test_coin_volume_at_default_size(tmp_path):
    _, summary = write_mesh(scenes.load("coin_pull"), tmp_path)
    assert abs(summary["coin_volume_rel_error"]) < 5e-3


def test_dolfinx_reads_dea_and_coin(tiny_scene, tmp_path):
    from mpi4py import MPI
    from deapull.fem_solver.compat import read_mesh, num_cells_global
    path, summary = write_mesh(tiny_scene("coin_pull"), tmp_path)
    mesh, ct, ft = read_mesh(path, MPI.COMM_WORLD)
    assert num_cells_global(mesh) == summary["groups"]["active"]["cells"] + summary["groups"]["passive"]["cells"]
    assert set(np.unique(ct.values)) == {groups.ACTIVE, groups.PASSIVE}
    assert {groups.CLAMP, groups.DEA_CONTACT, groups.ELECTRODE_TOP} <= set(np.unique(ft.values))
    coin, cct, cft = read_mesh(path, MPI.COMM_WORLD, volumes=("coin",))
    assert set(np.unique(cct.values)) == {groups.COIN}
    assert set(np.unique(cft.values)) == {groups.COIN_TOP, groups.COIN_BOTTOM}


def test_missing_mesh_and_missing_group(tiny_scene, tmp_path):
    from deapull.fem_solver.compat import MeshFileError, read_mesh
    with pytest.raises(MeshFileError, match="not found"):
        read_mesh(tmp_path / "nope.msh")
    path, _ = write_mesh(tiny_scene("free_bending"), tmp_path)
    with pytest.raises(MeshFileError, match="coin missing"):
        read_mesh(path, volumes=("coin",))


MPI_SCRIPT = """
import sys
import numpy as np
from mpi4py import MPI
from deapull.fem_solver.compat import read_mesh, num_cells_global
mesh, ct, ft = read_mesh(sys.argv[1], MPI.COMM_WORLD)
n_local = mesh.topology.index_map(3).size_local
tags = MPI.COMM_WORLD.allreduce(set(np.unique(ft.values).tolist()), op=MPI.BOR)
if MPI.COMM_WORLD.rank == 0:
    print("CELLS", num_cells_global(mesh), "SIZE", MPI.COMM_WORLD.size, "TAGS", sorted(tags))
"""


@pytest.mark.mpi
def test_dolfinx_reads_under_mpirun(tiny_scene, tmp_path):
    path, summary = write_mesh(tiny_scene("coin_pull"), tmp_path)
    script = tmp_path / "read.py"
    script.write_text(MPI_SCRIPT)
    proc = mpirun(2, str(script), str(path))
    assert proc.returncode == 0, proc.stderr
    n = summary["groups"]["active"]["cells"] + summary["groups"]["passive"]["cells"]
    assert f"CELLS {n} SIZE 2 TAGS [11, 12, 13, 14, 17]" in proc.stdout      # 17: the half model's mid-plane


@pytest.mark.parametrize("sym", ["half_z", "none"])
def test_tip_zone_and_rim_band_refine_where_the_tip_crosses_the_rim(tmp_path, sym):
    """The contact patch's own mesh: a 2 mm tip zone in 4 divisions and the band 3 <= |z| <= 5 mm
    in 4 per side give 0.5 x 0.5 mm underside facets there; the volumes are the same."""
    import dolfinx
    from mpi4py import MPI
    from deapull.fem_solver.compat import facets_with_tag, read_mesh
    sc = scenes.load("coin_pull", overrides=(f"mesh.symmetry='{sym}'", *SHARP, "mesh.n_length=16", "mesh.tip_zone_m=0.002",
                                             "mesh.tip_zone_divisions=4", "mesh.rim_band_m=[0.003, 0.005]",
                                             "mesh.rim_band_divisions=4"))
    path, summary = write_mesh(sc, tmp_path)
    half = sym == "half_z"
    # x: 4 + 16; z (half): 1 inside 3 mm, 4 in the band, 1 outside; full: mirrored, 1 across the middle
    across = 6 if half else 11
    assert summary["groups"]["dea_contact"]["cells"] == 20 * across
    d = sc.dea
    assert summary["groups"]["active"]["volume_m3"] == pytest.approx(
        d.length_m * d.width_m / (2 if half else 1) * d.active_thickness_m, rel=1e-9)
    mesh, _, ft = read_mesh(path, MPI.COMM_WORLD)
    facets = facets_with_tag(ft, groups.DEA_CONTACT)
    mid = dolfinx.mesh.compute_midpoints(mesh, 2, facets)
    patch = (mid[:, 0] < -d.length_m + 0.002) & (np.abs(mid[:, 2]) > 0.003) & (np.abs(mid[:, 2]) < 0.005)
    assert patch.sum() == 16 * (1 if half else 2)
    geom = dolfinx.cpp.mesh.entities_to_geometry(mesh._mesh, 2, facets[patch], False)
    corners = mesh.geometry.x[geom[:, :4]]
    assert np.allclose(np.ptp(corners[:, :, 0], axis=1), 5e-4) and np.allclose(np.ptp(corners[:, :, 2], axis=1), 5e-4)


def test_a_rim_band_outside_the_width_names_the_key():
    with pytest.raises(scenes.SceneError, match=r"mesh\.rim_band_m = \[0\.003, 0\.02\]"):
        scenes.load("coin_pull", overrides=("mesh.rim_band_m=[0.003, 0.02]",))
    with pytest.raises(scenes.SceneError, match=r"mesh\.tip_zone_m = 0\.03"):
        scenes.load("coin_pull", overrides=("mesh.tip_zone_m=0.03",))


@pytest.mark.parametrize("active_side", ["top", "bottom"])
def test_underside_grading_puts_the_smallest_elements_on_the_face_that_touches_the_coin(tmp_path, active_side):
    """``mesh.underside_grading`` = 4 on 3 divisions: the bottom layer's node planes are spaced
    s, 4^(1/3) s, 4^(2/3) s from the underside up (largest / smallest = 4), wherever the curve
    starts; the layer above keeps its uniform divisions, and the volumes do not change. Seen to
    fail: with the curve's direction taken from its first boundary point, not its
    parametrization (after the layers' fragment they differ), the largest element sat on the
    underside."""
    from mpi4py import MPI
    from deapull.fem_solver.compat import read_mesh
    n = 3
    sc = scenes.load("coin_pull", overrides=(*SHARP, f"dea.active_side='{active_side}'", f"mesh.n_active={n}",
                                             f"mesh.n_passive={n}", "mesh.underside_grading=4.0"))
    path, summary = write_mesh(sc, tmp_path)
    d = sc.dea
    assert summary["groups"]["active"]["volume_m3"] == pytest.approx(
        d.length_m * d.width_m / 2 * d.active_thickness_m, rel=1e-9)          # the half model
    mesh, _, _ = read_mesh(path, MPI.COMM_WORLD)
    y = mesh.geometry.x[:, 1]
    x = mesh.geometry.x[:, 0]
    dea = x < 0.0
    planes = np.unique(np.round(y[dea], 9))
    bottom_h = d.passive_thickness_m if active_side == "top" else d.active_thickness_m
    top_h = d.active_thickness_m if active_side == "top" else d.passive_thickness_m
    y_b = planes[0]
    # Q2 hexahedra: a node plane at each vertex plane and one midway; the vertex planes are every other one
    vertex = planes[::2]
    assert len(planes) == 2 * (2 * n) + 1
    lower = np.diff(vertex[:n + 1])
    r = 4.0 ** (1.0 / (n - 1))
    s = bottom_h * (r - 1) / (r ** n - 1)
    assert np.allclose(lower, s * r ** np.arange(n), rtol=1e-6), (lower, s)
    assert np.isclose(vertex[n] - y_b, bottom_h)
    assert np.allclose(np.diff(vertex[n:]), top_h / n, rtol=1e-6)


def test_the_rounded_free_edge_is_an_o_grid_of_sound_elements_on_the_arc(tmp_path):
    """coin_pull as shipped rounds the free bottom edge (r = 0.5 mm) with an O-grid: the passive
    layer loses exactly the corner's r^2 (1 - pi/4) per unit width (a sharp or chamfered corner
    does not: 1.3e-3 of the layer), the underside group is the flat underside plus the quarter
    arc (pi r / 2 per unit width), and no element is degenerate (the corner of a single mapped
    element would be: det J = 0 at its vertex on the arc). Broken once with each half of the arc
    replaced by its chord (a chamfer through the 45 degree point): the volume failed."""
    sc = scenes.load("coin_pull", overrides=("mesh.tip_zone_divisions=2", "mesh.rim_band_divisions=2"))
    d, r = sc.dea, sc.dea.free_edge_radius_m
    assert r == 0.0005 and sc.coin.edge_shape == "c2"
    _, summary = write_mesh(sc, tmp_path)
    half = d.width_m / 2
    corner = r ** 2 * (1 - math.pi / 4) * half
    assert summary["groups"]["passive"]["volume_m3"] == pytest.approx(
        d.length_m * half * d.passive_thickness_m - corner, rel=2e-5)
    assert summary["groups"]["dea_contact"]["area_m2"] == pytest.approx((d.length_m - r + math.pi * r / 2) * half,
                                                                        rel=2e-5)
    assert summary["min_quality_detj_ratio"] > 0.2


@pytest.mark.parametrize("radius_mm", [4.0, 5.0, 6.0])
def test_the_rim_band_follows_the_coin(radius_mm):
    """With mesh.rim_band_width_m the band is centred where the free edge at rest crosses the middle
    of the rim (rho = R - r_f / 2 at a distance c from the axis): it holds that crossing for a coin of
    4, 5 or 6 mm, and its width is the key's."""
    from deapull.meshing.build import rim_band
    sc = scenes.load("coin_pull", overrides=(f"coin.radius_m={radius_mm * 1e-3}",))
    c = sc.coin
    z = math.sqrt((c.radius_m - c.edge_radius_m / 2) ** 2 - c.center_from_tip_m ** 2)
    a, b = rim_band(sc)
    assert a < z < b and b - a == pytest.approx(sc.mesh.rim_band_width_m)
    assert 0 < a and b < sc.dea.width_m / 2
