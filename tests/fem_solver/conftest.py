"""Shared FEM fixtures: the test-size C3 run that the sweep's committed dataset was made from."""
from __future__ import annotations

import math
from pathlib import Path  # noqa: F401

import pytest

from deapull import scene as scenes
from tests.conftest import DATA, SHARP

#: the test-size C3 scene of tests/data/sweep/C3.nc (regenerate:
#: deapull solve --scene coin_pull --setup C3 --out DIR --set mesh.n_length=8 --set mesh.n_width=1
#: --set mesh.coin_size_m=0.004)
#: (pinned to the discretisation the fixture was made with: the full model, MUMPS, the
#: friction regularisation eps_v = 1e-4 m/s and the placement's first try at full gravity,
#: the defaults before 2026-11-23; its penalty 10 E / h_tip = 1.12e9 N/m^3 on this 8-element mesh;
#: the table, which the fixture did not have, 1 m down where nothing reaches it)
C3_TEST = (*SHARP, "mesh.n_length=8", "mesh.n_width=1", "mesh.coin_size_m=0.004", "mesh.symmetry='none'",
           "solver.linear_solver='mumps'", "contact.slip_rate_regularisation_m_s=1e-4",
           "time.placement_first_step=1.0", "contact.quadrature_degree=4", "contact.penalty_N_m3=1120000000.0",
           "table.height_m=-1.0")
#: the records of that run as the code before the stepping API wrote them (every variable)
C3_REFERENCE = DATA / "sweep" / "C3.nc"


def c3_reference() -> Path:
    if not C3_REFERENCE.is_file():
        pytest.fail(f"reference dataset {C3_REFERENCE} is missing")
    return C3_REFERENCE


def balance_bound_N(scene, num_dofs: int) -> float:
    """Largest independent force-balance residual a converged step can leave (N).

    The clamp-reaction force differs from the contact integral by the sum of the residual
    over the free rows of one component, at most √n · ‖R‖₂ ≤ √n · atol (Cauchy–Schwarz;
    Newton stops at ‖R‖₂ ≤ atol, the absolute tolerance binds). The balance takes
    Fx and μ_b·Fy: (1 + μ_b) √n · atol.
    """
    return (1 + scene.coin.mu_b) * math.sqrt(num_dofs) * scene.solver.newton_atol


@pytest.fixture(scope="session")
def c3_run(tmp_path_factory):
    """(scene, dataset path) of the test-size C3 run with today's code (~4 s)."""
    from deapull.fem_solver import stepping
    from deapull.fem_solver.run import solve_scene
    from deapull.fem_solver.stepping import Stepper
    sc = scenes.load("coin_pull", setup="C3", overrides=(*C3_TEST, "solver.predictor='linear'"))
    # the solver path as the fixture's code had it: the coupling's first guess without the
    # acceleration term, the linear predictor, the placement on the scene's Newton at the fixture's penalty; the records
    # then agree to round-off (test_stepping.py measures what the acceleration changes)
    kept = stepping.PLACEMENT_PENALTY_N_M3
    Stepper.PREDICT_ACCELERATION = Stepper.PLACEMENT_FULL_NEWTON = False
    stepping.PLACEMENT_PENALTY_N_M3 = math.inf
    try:
        return sc, solve_scene(sc, tmp_path_factory.mktemp("c3"), progress=False)
    finally:
        Stepper.PREDICT_ACCELERATION = Stepper.PLACEMENT_FULL_NEWTON = True
        stepping.PLACEMENT_PENALTY_N_M3 = kept
