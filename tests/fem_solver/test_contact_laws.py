"""Physics of the DEA–obstacle contact (fem_solver/contact.py, issue 23 item 7): the penalty
(Winkler) foundation's load–indentation laws on the coin's flat top and on its rounded rim,
the direction of the normal force on the rim, Coulomb friction on a sliding block, and that
the penalty only adds its own compliance to a solved equilibrium.

As in test_table.py the DEA is moved rigidly (translated, or rotated about z) and the
reactions are assembled without a solve, except in the last test. Every expected value comes
from outside the code under test: the area of a disc cut by a chord, the closed-form Winkler
integrals of a plate pressed onto a circular cylinder (the rim's fillet), Coulomb's law.

The laws (k_n the penalty, d the indentation, w the DEA's width):

* flat punch: F = k_n d A, A the overlap of the punch face and the DEA's underside;
* a plate tangent to a cylinder of radius R along a line of length w, pressed by d
  (the contact strip |σ| < a, a² = R² − c², c = R − d; depth R − √(c² + σ²), normal along
  the cylinder's radius): F = ∫ k_n (R − s) c/s dσ w = 2 k_n w c (R asinh(a/c) − a), along
  the plate's normal; to leading order F = (4/3) k_n w √(2R) d^{3/2};
* a horizontal plate at height top − d whose edge lies at t₁ from where the fillet of radius
  R starts (t₁ < 0: over the flat top): over the fillet (t ∈ [max(t₁, 0), a])
  F_y = k_n w c (R (asinh(a/c) − asinh(t/c)) − (a − t)) and F_x = −k_n w (R − √(t² + c²))²/2
  (the obstacle pushed back), plus k_n w d (−t₁) on F_y from the flat top when t₁ < 0.

The rim tests use a stop of radius 10 km (a straight rim across the DEA's 20 mm width: the
sagitta (w/2)²/(2 R_stop) = 5 nm is < 1e-3 of the indentations used) with a 10 mm fillet,
so that the contact strips are mm wide and a 0.5 mm tip-zone mesh resolves them.

Each test was seen to fail once with the code under test broken (then restored):

* flat punch: ρ without its z part in contact.py (the disc becomes a strip); the coin's
  centre passed 0.5 mm off in problem.py; p_n scaled by 1.01 in contact.py (+0.6 %
  against the 0.5 % tolerance);
* rim law: the fillet branch dropped (corner indicator always 0: a square rim; 394 N
  against 2.98 N);
* friction: the obstacle's motion left out of the slip rate (the moving-obstacle case);
  the friction's sign flipped (the three slips along x);
* the rim's normal (single contact line and the slide over the rim): the fillet's normal
  replaced by e_y (Fx = 0);
* penalty: problem.py passing a fixed 2.24e9 instead of contact.penalty_N_m3 (the
  penetration no longer shrinks).
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from mpi4py import MPI

from deapull import scene as scenes
from deapull.fem_solver import compat
from deapull.fem_solver.problem import DEAProblem
from deapull.fem_solver.simulation import Simulation, mesh_scene
from deapull.meshing.layout import layout
from tests.conftest import SHARP

#: mesh of the rigid-motion tests: 12 mm from the free end in 1 mm (x) by 1 mm (z) facets,
#: over the coin (whose far rim is 8 mm from the free end), the rest in two elements
FINE_TIP = ("mesh.n_length=2", "mesh.tip_zone_m=0.012", "mesh.tip_zone_divisions=12", "mesh.n_width=20",
            "mesh.symmetry='none'")

#: the real coin (r = 5 mm, centre 3 mm from the free end) with a sharp rim: a flat punch (its
#: 1 µm fillet, and the side wall's band r − d < ρ < r, change the force by ~d / r < 1e-3)
FLAT_PUNCH = (*SHARP, "coin.edge_radius_m=1e-6", "table.height_m=-1.0", *FINE_TIP)

#: the straight rim (see the module docstring): where the fillet starts, from the free end (m)
RIM_START_FROM_TIP_M = 0.004
STOP_RADIUS_M, FILLET_M = 1e4, 0.01
RIM = (f"stop.radius_m={STOP_RADIUS_M!r}", f"stop.edge_radius_m={FILLET_M!r}", "stop.height_m=0.02",
       f"stop.center_from_tip_m={RIM_START_FROM_TIP_M - (STOP_RADIUS_M - FILLET_M)!r}",
       # 0.5 mm facets over the 12 mm from the free end; the problem is uniform in z
       "mesh.n_length=2", "mesh.tip_zone_m=0.012", "mesh.tip_zone_divisions=24", "mesh.n_width=1",
       "mesh.symmetry='none'", "contact.quadrature_degree=8")


def _problem(tmp_path, name, *overrides):
    sc = scenes.load(name, overrides=overrides)
    msh, _ = mesh_scene(sc, tmp_path / "mesh", MPI.COMM_WORLD)
    mesh, ct, ft = compat.read_mesh(msh)
    return sc, DEAProblem(sc, mesh, ct, ft)


def _place(problem, at, angle_rad=0.0, pivot_from_tip_m=0.0, slip_m=(0.0, 0.0), X_m=0.0, X_moved_m=0.0, dt=1.0):
    """Move the DEA rigidly: rotate it by ``angle_rad`` about z (counter-clockwise in x–y)
    about the point of its underside ``pivot_from_tip_m`` from the free end, and translate it
    so that this point lies at ``at`` = (x, y). The old state is this one less ``slip_m`` =
    (Δx, Δz), and the obstacle is displaced by ``X_m`` along x, ``X_moved_m`` of it since the
    old state; the step is ``dt``."""
    lay = layout(problem.scene)
    coords, dofs = compat.displacement_dofs(problem.W, problem.has_parts)
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    rx, ry = coords[:, 0] - (-lay.length_m + pivot_from_tip_m), coords[:, 1] - lay.y_bottom_m
    problem.w.x.array[:] = 0.0
    problem.w.x.array[dofs[:, 0]] = at[0] + c * rx - s * ry - coords[:, 0] - slip_m[0]
    problem.w.x.array[dofs[:, 1]] = at[1] + s * rx + c * ry - coords[:, 1]
    problem.w.x.array[dofs[:, 2]] = -slip_m[1]
    problem.w_old.x.array[:] = problem.w.x.array
    problem.w.x.array[dofs[:, 0]] += slip_m[0]
    problem.w.x.array[dofs[:, 2]] += slip_m[1]
    problem.X_old.value = X_m - X_moved_m
    problem.set_load(0.0, X_m, dt)


def _press(problem, depth_m, tip_shift_m=0.0, **kw):
    """Translate the DEA so that its flat underside is ``depth_m`` below the obstacle's top and
    its free end ``tip_shift_m`` further along x than in the reference configuration."""
    lay = layout(problem.scene)
    _place(problem, (-lay.length_m + tip_shift_m, lay.obstacle_top_y_m - depth_m), **kw)


def _disc_cut_by_chord(r, h):
    """Area of the part of a disc of radius r on one side of a chord at distance h from its
    centre, the side with the centre."""
    return math.pi * r ** 2 - (r ** 2 * math.acos(h / r) - h * math.sqrt(r ** 2 - h ** 2))


def _fillet_line_force(k_n, width, R, d):
    """Winkler force of a plate pressed by ``d`` onto a cylinder of radius ``R`` along a line of
    length ``width`` (module docstring): 2 k_n w c (R asinh(a/c) − a), c = R − d, a² = R² − c²."""
    c = R - d
    a = math.sqrt(R ** 2 - c ** 2)
    return 2 * k_n * width * c * (R * math.asinh(a / c) - a)


def _edge_over_fillet(k_n, width, R, d, t1):
    """(Fx, Fy) on the obstacle of a horizontal plate ``d`` below the top whose edge lies ``t1``
    beyond the start of the fillet of radius ``R`` (module docstring; the plate covers t > t1)."""
    c = R - d
    a = math.sqrt(R ** 2 - c ** 2)
    t = min(max(t1, 0.0), a)
    Fy = k_n * width * (c * (R * (math.asinh(a / c) - math.asinh(t / c)) - (a - t)) + d * max(-t1, 0.0))
    Fx = -k_n * width * (R - math.hypot(t, c)) ** 2 / 2
    return Fx, Fy


# --- the flat punch: the coin's top face ----------------------------------------------

@pytest.fixture(scope="module")
def punch(tmp_path_factory):
    return _problem(tmp_path_factory.mktemp("punch"), "coin_pull", *FLAT_PUNCH)


def test_flat_punch_force_is_penalty_times_depth_times_the_cut_disc(punch):
    """The coin's top under the DEA is its disc less the segment beyond the free end (the chord
    at center_from_tip_m = 3 mm from the centre): Fy = k_n d A, linear in d (Winkler)."""
    sc, p = punch
    k_n, coin = sc.contact.penalty_N_m3, sc.coin
    area = _disc_cut_by_chord(coin.radius_m, coin.center_from_tip_m)
    depth = 2e-6
    _press(p, depth)
    _, Fy = p.obstacle_forces()
    # measured -0.40 %: the 5 x 5 Gauss points per 1 mm facet sample the disc's edge
    assert Fy == pytest.approx(k_n * depth * area, rel=5e-3)
    _press(p, 2 * depth)
    _, Fy2 = p.obstacle_forces()
    assert Fy2 / Fy == pytest.approx(2.0, rel=1e-9)     # the same points, each twice as deep
    _press(p, depth, tip_shift_m=2 * coin.radius_m)   # free end beyond the coin's far rim
    assert p.obstacle_forces() == (0.0, 0.0)


# --- the rounded rim -------------------------------------------------------------------

@pytest.fixture(scope="module")
def rim(tmp_path_factory):
    sc, p = _problem(tmp_path_factory.mktemp("rim"), "blocked_force", *RIM)
    p.mu_t.value = 0.0                                  # frictionless: the normal part alone
    lay = layout(sc)
    # the fillet's axis in the x-y plane: where the top face ends, a fillet radius down
    axis = (-lay.length_m + RIM_START_FROM_TIP_M, lay.obstacle_top_y_m - FILLET_M)
    return sc, p, axis


def _press_tangent(p, axis, angle_rad, depth_m):
    """Tilt the DEA so that its underside is tangent to the fillet where the fillet's normal
    is ``angle_rad`` from the vertical, pressed ``depth_m`` into it; the tangent line runs
    across the DEA 6 mm from its free end (in the 0.5 mm tip zone)."""
    reach = FILLET_M - depth_m
    at = (axis[0] + reach * math.sin(angle_rad), axis[1] + reach * math.cos(angle_rad))
    _place(p, at, angle_rad=-angle_rad, pivot_from_tip_m=0.006)


def test_plate_on_the_rim_fillet_follows_the_winkler_cylinder_law(rim):
    """A plate tangent to the fillet (a cylinder of radius r_f along the DEA's width), pressed
    d = 50 and 100 µm: F = 2 k_n w c (r_f asinh(a/c) − a) → (4/3) k_n w √(2 r_f) d^{3/2}."""
    sc, p, axis = rim
    k_n, w = sc.contact.penalty_N_m3, sc.dea.width_m
    force = {}
    for d in (50e-6, 100e-6):
        _press_tangent(p, axis, math.radians(45), d)
        force[d] = math.hypot(*p.obstacle_forces())
        # measured -0.02 %: 2.0 / 2.8 mm wide strips over 0.5 mm facets
        assert force[d] == pytest.approx(_fillet_line_force(k_n, w, FILLET_M, d), rel=2e-3)
        # the leading-order law (d / r_f = 0.5 / 1 %: its own error -0.3 / -0.6 %)
        assert force[d] == pytest.approx(4 / 3 * k_n * w * math.sqrt(2 * FILLET_M) * d ** 1.5, rel=1e-2)
    exponent = math.log(force[100e-6] / force[50e-6]) / math.log(2)
    assert exponent == pytest.approx(1.5, abs=0.01)    # measured 1.4960 (closed form: 1.4960)


@pytest.mark.parametrize("angle_deg", [30.0, 60.0])
def test_a_single_contact_line_on_the_rim_pushes_along_the_fillet_normal(rim, angle_deg):
    """Tangent to the fillet at an angle θ from the top: the strip's tractions are symmetric
    about the tangent line, so the force on the obstacle is along minus the fillet's normal
    there: −Fx / Fy = tan θ (it is pushed down and back toward its centre)."""
    sc, p, axis = rim
    theta = math.radians(angle_deg)
    _press_tangent(p, axis, theta, 100e-6)
    Fx, Fy = p.obstacle_forces()
    assert Fy > 0 and Fx < 0
    assert -Fx / Fy == pytest.approx(math.tan(theta), rel=1e-5)   # measured 2e-8
    # the patch probe's normal part is that push (frictionless: all of Fx)
    assert -p.patch_probe(())[1] / Fy == pytest.approx(math.tan(theta), rel=1e-5)
    assert math.hypot(Fx, Fy) == pytest.approx(_fillet_line_force(sc.contact.penalty_N_m3, sc.dea.width_m,
                                                                  FILLET_M, 100e-6), rel=2e-3)


def test_block_sliding_over_the_rim_at_fixed_height_meets_no_jump(rim):
    """The DEA held flat 100 µm below the top and slid along x so that its free end goes from
    1 mm over the flat top, across the fillet's start, to beyond the contact (a = 1.41 mm into
    the fillet): Fx and Fy follow the closed forms (module docstring) at every position, and
    between neighbouring positions Fy changes by no more than its largest slope k_n w d times
    the shift (no jump where the top face gives way to the fillet)."""
    sc, p, _ = rim
    k_n, w, d = sc.contact.penalty_N_m3, sc.dea.width_m, 100e-6
    positions = np.linspace(-1e-3, 1.6e-3, 53)           # 50 µm apart
    got, want = [], []
    for t1 in positions:
        _press(p, d, tip_shift_m=RIM_START_FROM_TIP_M + t1)
        got.append(p.obstacle_forces())
        want.append(_edge_over_fillet(k_n, w, FILLET_M, d, t1))
    got, want = np.array(got), np.array(want)
    scale = np.abs(want).max(axis=0)                      # the largest Fx and Fy
    # measured: Fx within 4e-3 and Fy within 8e-4 of their largest, the worst where the strip
    # left under the plate is narrower than the 0.1 mm between quadrature points
    assert np.all(np.abs(got - want) <= [1e-2, 2.5e-3] * scale)
    assert np.all(got[positions > 1.5e-3] == 0.0)        # beyond a: nothing touches
    steps = np.abs(np.diff(got[:, 1]))
    assert steps.max() <= 1.1 * k_n * w * d * (positions[1] - positions[0])   # measured 1.05


# --- friction on a sliding block -------------------------------------------------------

@pytest.mark.parametrize("slip, X_moved, sign", [((2e-3, 0.0), 0.0, 1.0), ((-2e-3, 0.0), 0.0, -1.0),
                                                 ((0.0, 0.0), 2e-3, -1.0), ((0.0, 2e-3), 0.0, 0.0)])
def test_sliding_block_drags_the_obstacle_along_its_slip_at_mu_t_times_the_pressing_force(rim, slip, X_moved,
                                                                                         sign):
    """The DEA pressed 2 µm onto the flat top (the stop moved 50 mm along x, so that its top
    covers the whole underside: a uniform patch, Fy = k_n d L w) and slid 2 mm in 1 s (the DEA by
    ``slip``, or the obstacle by ``X_moved``): 200 times the regularisation ε_v = 1e-5 m/s, so
    Coulomb's |t| = μ_t p_n to 1.3e-5. The DEA drags the obstacle along the DEA's slip relative
    to it (the obstacle's force on the DEA opposes that slip); a slip along z pushes nothing
    along x; friction leaves the pressing force alone."""
    sc, p, _ = rim
    mu, depth = 0.55, 2e-6                                # the coin's μ_t in C3
    _press(p, depth, slip_m=slip, X_m=0.05, X_moved_m=X_moved)
    p.mu_t.value = mu
    try:
        Fx, Fy = p.obstacle_forces()
    finally:
        p.mu_t.value = 0.0
    assert Fy == pytest.approx(sc.contact.penalty_N_m3 * depth * sc.dea.length_m * sc.dea.width_m, rel=1e-9)
    if sign:
        assert Fx == pytest.approx(sign * mu * Fy, rel=5e-5)
    else:
        assert abs(Fx) < 1e-12 * Fy


# --- the patch probe: the friction–speed curve any coin under the patch would feel -------------

def _friction_of_a_uniform_spread(v_lo, v_hi, coin, eps):
    """Mean over v uniform in [v_lo, v_hi] of the regularised sign (v − U)/√((v − U)² + ε²)."""
    a, b = v_lo - coin, v_hi - coin
    return (math.hypot(b, eps) - math.hypot(a, eps)) / (b - a)


@pytest.mark.parametrize("spread", [0.0, 1e-5])
def test_the_patch_probe_reads_the_friction_speed_curve_of_a_sheared_patch(rim, spread):
    """The DEA pressed 2 µm onto the flat top (uniform pressure) and moved in 1 s so that its
    underside's x velocity runs linearly across the width, v_x = v̄ + 2 s z / w, with v̄ = 2 mm/s
    and s = 0 (a rigid slide) or ε_v: uniform in [v̄ − s, v̄ + s]. The probe gives v̄, no normal
    push along x, and at each coin speed U = c v̄ the drag per unit μ of that uniform spread,
    Fy (√((v̄ + s − U)² + ε²) − √((v̄ − s − U)² + ε²)) / 2s, or Fy (v̄ − U)/√((v̄ − U)² + ε²) for s = 0.
    (s is ε_v so that the rule's five points across the width integrate the smooth sign: a
    spread of many ε_v puts a kink between them.)"""
    sc, p, _ = rim
    vbar, depth, eps = 2e-3, 2e-6, sc.contact.slip_rate_regularisation_m_s
    _press(p, depth, slip_m=(vbar, 0.0), X_m=0.05)
    coords, dofs = compat.displacement_dofs(p.W, p.has_parts)
    p.w_old.x.array[dofs[:, 0]] -= 2 * spread * coords[:, 2] / sc.dea.width_m   # dt = 1 s
    shares = (0.0, 0.9, 1 - 0.5 * eps / vbar, 1.0, 1 + 0.5 * eps / vbar, 1.2)
    vx, normal_x, drags = p.patch_probe(shares)
    Fy = p.obstacle_forces()[1]
    assert vx == pytest.approx(vbar, rel=1e-9)
    assert abs(normal_x) < 1e-12 * Fy
    for c, drag in zip(shares, drags):
        if spread:
            want = _friction_of_a_uniform_spread(vbar - spread, vbar + spread, c * vbar, eps)
        else:
            want = (1 - c) * vbar / math.hypot((1 - c) * vbar, eps)
        # the rule's own error across the width (5-point Gauss): 2e-5
        assert drag / Fy == pytest.approx(want, abs=1e-4), c


# --- the penalty's compliance ----------------------------------------------------------

#: the DEA let down onto the coin under gravity (V = 0), 1 mm facets along x over the coin, no table
RESTING = (*SHARP, "mesh.n_length=4", "mesh.tip_zone_m=0.008", "mesh.tip_zone_divisions=8", "mesh.n_width=4",
           "mesh.symmetry='half_z'", "table.height_m=-1.0")


def _rest_on_the_coin(tmp_path, penalty):
    """(Fy, penetration, tip u_y) of the DEA placed on the coin under gravity; the penetration
    from the current positions of the contact points over the coin's flat top (m)."""
    sim = Simulation.from_scene(scenes.load("coin_pull", overrides=(*RESTING, f"contact.penalty_N_m3={penalty!r}")),
                                mesh_dir=tmp_path / f"k{penalty:g}")
    stepper = sim.stepper(progress=False)
    rec = stepper.start(0.0)
    lay, coin = sim.layout, sim.scene.coin
    x = stepper.p._positions_at("contact")
    over_top = np.hypot(x[:, 0] - lay.obstacle_center_x_m, x[:, 2]) < coin.radius_m - coin.edge_radius_m
    return rec.Fy, float(np.max(lay.obstacle_top_y_m - x[over_top, 1])), rec.tip_uy


def test_a_ten_times_stiffer_penalty_only_takes_its_compliance_out(tmp_path):
    """The DEA resting on the coin with k_n and 10 k_n: the pressing force (set by the DEA's
    weight and stiffness) moves < 1 %; the penetration shrinks between 1/10 (a conforming
    patch of fixed area: δ = F / (k_n A)) and 1/√10 (a plate's edge on a flat, a Winkler
    wedge: F ∝ k_n δ²); and the tip comes up by about the penetration given back."""
    k_n = scenes.load("coin_pull").contact.penalty_N_m3
    F1, d1, uy1 = _rest_on_the_coin(tmp_path, k_n)
    F10, d10, uy10 = _rest_on_the_coin(tmp_path, 10 * k_n)
    assert F1 > 0 and d1 > 0
    assert F10 == pytest.approx(F1, rel=1e-2)                 # measured +0.14 %
    assert 0.1 - 1e-3 <= d10 / d1 <= 10 ** -0.5               # measured 0.143
    assert uy10 - uy1 == pytest.approx(d1 - d10, rel=0.25)    # measured 3.18 µm against 3.03 µm


# --- the rounded free edge ---------------------------------------------------------------

#: the DEA's free bottom edge rounded (r = 0.5 mm, its O-grid at 4 elements per half arc) over a
#: flat stop (radius 10 km, a 1 µm rim: the whole DEA lies over its top face)
EDGE_R = 5e-4
FLAT_STOP = ("stop.radius_m=1e4", "stop.edge_radius_m=1e-6", "stop.center_from_tip_m=0.0",
             f"dea.free_edge_radius_m={EDGE_R!r}", "mesh.n_length=2", "mesh.tip_zone_m=0.002",
             "mesh.tip_zone_divisions=3", "mesh.free_edge_divisions=4", "mesh.n_width=1", "mesh.symmetry='half_z'",
             "contact.quadrature_degree=20", "table.height_m=-1.0")


def _cylinder_on_winkler(k_n, width, R, d):
    """Force of a cylinder of radius R pressed d into a Winkler foundation (penetration measured
    normal to the flat), integrated over the cylinder's surface: w k_n R ∫ (d − R + R cos φ) dφ
    over |φ| < φ_m, cos φ_m = 1 − d/R; to leading order (4/3) k_n w √(2R) d^{3/2}."""
    phi = math.acos(1 - d / R)
    return 2 * k_n * width * R * ((d - R) * phi + R * math.sin(phi))


@pytest.mark.parametrize("tilt_deg", [20.0, 45.0])
def test_the_rounded_free_edge_pressed_into_a_flat_follows_the_cylinder_law(tmp_path, tilt_deg):
    """The DEA tilted nose-down by θ (so that the lowest point of its rounded edge lies on the arc)
    and pressed d = 10 and 20 µm into a flat stop: only the arc touches, the force is that of a
    cylinder of the edge's radius on the penalty foundation, its exponent 3/2, and it pushes straight
    down. This checks the O-grid's arc (second-order geometry) and the contact points pushed through
    the curved cells. Broken twice: with the facet points mapped by the facet's vertices only (off
    the arc), the deepest point's depth failed; with each half of the arc meshed as its chord, the
    force failed."""
    sc, p = _problem(tmp_path, "blocked_force", *FLAT_STOP)
    p.mu_t.value = 0.0
    lay = layout(sc)
    top, k_n, theta = lay.obstacle_top_y_m, sc.stop and sc.contact.penalty_N_m3, math.radians(tilt_deg)
    force = {}
    for d in (10e-6, 20e-6):
        # rotate about the arc's underside tangent point B (r from the free end); the arc's centre
        # sits r above B, so its lowest point lies r (1 - cos θ) above where B is placed
        _place(p, (-lay.length_m + EDGE_R, top - d + EDGE_R * (1 - math.cos(theta))), angle_rad=theta,
               pivot_from_tip_m=EDGE_R)
        Fx, Fy = p.obstacle_forces()
        force[d] = Fy
        assert Fy == pytest.approx(_cylinder_on_winkler(k_n, lay.width_m, EDGE_R, d), rel=5e-3)   # measured <= 0.11 %
        assert abs(Fx) < 1e-9 * Fy                       # frictionless on a flat: straight down
        print(f"theta {tilt_deg} d {d}: Fy / law - 1 = {Fy / _cylinder_on_winkler(k_n, lay.width_m, EDGE_R, d) - 1:.2e}, "
              f"deepest point {p.max_penetration_at_points():.4e}")
        # the solver's own contact points lie on the arc: the deepest is d in
        assert p.max_penetration_at_points() == pytest.approx(d, abs=5e-8)
    exponent = math.log(force[20e-6] / force[10e-6]) / math.log(2)
    assert exponent == pytest.approx(math.log(_cylinder_on_winkler(1, 1, EDGE_R, 20e-6)
                                              / _cylinder_on_winkler(1, 1, EDGE_R, 10e-6)) / math.log(2), abs=0.01)
