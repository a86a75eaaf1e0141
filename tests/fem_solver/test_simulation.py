"""Simulation.from_scene, the one scene → mesh → problem → stepper path: one solve reads its
``.msh`` once and computes the scene's layout once; the coin mass from that read is the mesh
volume × density; a setup cannot be given twice."""
import gmsh
import pytest
import ufl
import xarray as xr
from mpi4py import MPI

from deapull.errors import InputError
from deapull.fem_solver import compat
from deapull.fem_solver.run import solve_scene
from deapull.fem_solver.simulation import Simulation
from deapull.meshing import layout as layouts
from deapull.meshing.layout import layout


@pytest.fixture
def count_reads(monkeypatch):
    """Counts every gmsh read of a mesh file (``gmsh.merge``) from now on."""
    calls = []
    merge = gmsh.merge

    def counted(path):
        calls.append(path)
        return merge(path)
    monkeypatch.setattr(gmsh, "merge", counted)
    return calls


@pytest.fixture
def count_layouts(monkeypatch):
    """Counts every Layout built from now on (the cache emptied first)."""
    made, build = [], layouts.Layout

    def counted(*args, **kwargs):
        made.append(build(*args, **kwargs))
        return made[-1]
    clear = getattr(layout, "cache_clear", lambda: None)
    clear()
    monkeypatch.setattr(layouts, "Layout", counted)
    yield made
    clear()


def test_one_solve_reads_the_msh_once_and_computes_the_layout_once(tiny_scene, tmp_path, count_reads,
                                                                     count_layouts):
    sc = tiny_scene("coin_pull", "load.end_time_s=0.02", setup="C3")
    with xr.open_dataset(solve_scene(sc, tmp_path, progress=False)) as ds:
        mass_kg = ds.attrs["coin_mass_kg"]
    assert len(count_reads) == 1 and count_reads[0].endswith("mesh.msh")
    assert len(count_layouts) == 1          # computed once; the mesher and the problem reuse it
    assert mass_kg > 0


def test_the_coin_mass_is_the_coin_mesh_volume_times_the_density(tiny_scene, tmp_path):
    """Against the coin's mesh volume read on its own and assembled by dolfinx on the coin's
    (second-order) mesh: the same number to the bit (the datasets made before the one read
    stay reproducible); and against the mesher's own Gauss quadrature of it in gmsh."""
    sc = tiny_scene("coin_pull", setup="C3")
    sim = Simulation.from_scene(sc, mesh_dir=tmp_path)
    coin, _, _ = compat.read_mesh(sim.mesh_path, MPI.COMM_WORLD, volumes=("coin",))
    volume = compat.assemble_scalar(compat.form(1.0 * ufl.dx(domain=coin)), MPI.COMM_WORLD)
    assert sim.mass_kg == volume * sc.coin.density_kg_m3
    gauss = sim.mesh_summary["groups"]["coin"]["volume_m3"]
    assert sim.mass_kg == pytest.approx(gauss * sc.coin.density_kg_m3, rel=1e-11)
    assert sim.layout is layout(sc)


def test_a_scene_without_a_coin_has_no_mass(tiny_scene, tmp_path):
    sim = Simulation.from_scene(tiny_scene("free_bending"), mesh_dir=tmp_path)
    assert sim.mass_kg is None and sim.stepper(progress=False).mass_kg is None


def test_a_setup_given_twice_is_refused_before_meshing(tiny_scene, tmp_path):
    sc = tiny_scene("coin_pull", setup="C3")
    with pytest.raises(InputError, match=r"setup='C1'.*already resolved at setup 'C3'"):
        Simulation.from_scene(sc, "C1", mesh_dir=tmp_path)
    assert not any(tmp_path.iterdir())
