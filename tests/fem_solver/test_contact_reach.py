"""The contact integral covers only the underside facets within reach of the obstacle
(``contact.reach_m``: 5 mm in coin_pull; fem_solver/problem.py), and says so loudly when the DEA touches the obstacle
outside them. That the reach changes no result is checked to round-off by
test_stepping.py::test_run_reproduces_the_records_before_the_stepping_api (the same C3 run)."""
from __future__ import annotations

import numpy as np
import pytest

from deapull import scene as scenes
from deapull.fem_solver import compat
from deapull.fem_solver import problem as problem_module
from deapull.fem_solver.simulation import Simulation
from tests.fem_solver.conftest import C3_TEST


@pytest.fixture(scope="module")
def c3_sim(tmp_path_factory):
    return Simulation.from_scene(scenes.load("coin_pull", setup="C3", overrides=C3_TEST),
                                 mesh_dir=tmp_path_factory.mktemp("reach"))


def test_the_reach_leaves_out_the_facets_far_from_the_coin(c3_sim):
    p = c3_sim.problem()
    lay = c3_sim.layout
    points, _ = p.contact_points()
    assert len(compat.facets_with_tag(p._facet_tags, problem_module.OUT_OF_REACH)) > 0   # some are left out
    assert c3_sim.scene.contact.reach_m > 0
    far = lay.obstacle_center_x_m + lay.obstacle_radius_m + c3_sim.scene.contact.reach_m
    assert points[:, 0].min() < lay.obstacle_center_x_m     # the tip, over the coin, is in
    # no point of the integral lies beyond the facets that overlap the widened footprint
    assert points[:, 0].max() < far + c3_sim.scene.dea.length_m / c3_sim.scene.mesh.n_length


def test_touching_outside_the_contact_facets_is_refused(c3_sim, monkeypatch):
    """A reach that misses the tip (only the facets beyond the coin's far rim kept): the DEA
    sinks into the coin at the placement, where the integral cannot see it, and the first
    record refuses the state."""
    original = problem_module.DEAProblem._contact_reach

    def far_only(self, mesh, facet_tags):
        tags = original(self, mesh, facet_tags)
        geom = problem_module.dolfinx.cpp.mesh.entities_to_geometry(mesh._mesh, 2, tags.indices, False)
        x_min = mesh.geometry.x[geom][:, :, 0].min(axis=1)
        lay = self.layout
        near = (tags.values == problem_module.groups.DEA_CONTACT) & (x_min <= lay.obstacle_center_x_m + lay.obstacle_radius_m)
        values = np.where(near, problem_module.OUT_OF_REACH, tags.values).astype(np.int32)
        return problem_module.dolfinx.mesh.meshtags(mesh, 2, tags.indices, values)

    monkeypatch.setattr(problem_module.DEAProblem, "_contact_reach", far_only)
    stepper = c3_sim.stepper(progress=False)
    with pytest.raises(problem_module.ContactOutOfReach, match="contact.reach_m"):
        stepper.start()
