"""Coulomb block: the rigid coin under a prescribed force ramp against the closed-form solution."""
import numpy as np
import pytest

from deapull.fem_solver.coin import CoinState, coulomb_step, force_balance_residual

M, MU, G = 1.36e-3, 0.2, 9.8


def analytic(t, rate, Fy):
    """Coin under Fx = −rate·t (toward −x): at rest until rate·t = μN, then m a = F − μN."""
    N = M * G + Fy
    t0 = MU * N / rate
    tau = np.maximum(t - t0, 0.0)
    u = -rate * tau ** 2 / (2 * M)
    x = -rate * tau ** 3 / (6 * M)
    return x, u, t0


@pytest.mark.parametrize("Fy", [0.0, 5e-3])
def test_coulomb_block_force_ramp(Fy):
    rate, dt = 0.05, 1e-4          # N/s
    state, xs, us, stuck_until = CoinState(), [], [], None
    ts = np.arange(1, 6001) * dt
    for t in ts:
        new = coulomb_step(state, -rate * t, Fy, dt, M, MU, G)
        if stuck_until is None and not new.stick:
            stuck_until = t
        assert force_balance_residual(state, new, -rate * t, Fy, dt, M, MU, G) < 1e-12
        state = new
        xs.append(state.x)
        us.append(state.u)
    x_ref, u_ref, t0 = analytic(ts, rate, Fy)
    assert stuck_until == pytest.approx(t0, abs=2 * dt)            # starts sliding at F = μ_b N
    assert np.max(np.abs(np.array(us) - u_ref)) < 2e-3 * np.max(np.abs(u_ref))
    assert np.max(np.abs(np.array(xs) - x_ref)) < 5e-3 * np.max(np.abs(x_ref))


def test_sliding_coin_decelerates_at_mu_g_and_stops():
    state, dt = CoinState(0.0, -0.01, False), 1e-4
    t = 0.0
    while not state.stick:
        state = coulomb_step(state, 0.0, 0.0, dt, M, MU, G)
        t += dt
    assert t == pytest.approx(0.01 / (MU * G), abs=2 * dt)
    # backward Euler: the distance is short by at most one step at the initial speed
    assert state.x == pytest.approx(-0.01 ** 2 / (2 * MU * G), abs=dt * 0.01)


def test_static_friction_holds_below_the_cone():
    state = coulomb_step(CoinState(), -0.99 * MU * M * G, 0.0, 1e-3, M, MU, G)
    assert state.stick and state.x == 0.0 and state.u == 0.0


def test_penetration_measure_uses_the_contact_s_rounded_rim():
    """The nodal penetration is the contact's own signed distance: flat top, side wall and
    fillet, so a point above the sharp corner (outside the rounded rim) is not 'inside'."""
    from deapull.fem_solver.contact import rounded_cylinder_distance
    top, radius, fillet = 1.0e-3, 5e-3, 3e-4
    rho = np.array([0.0, 0.0, radius + 2e-5, radius, radius - fillet + fillet / np.sqrt(2)])
    y = np.array([top - 4e-5, top + 1e-5, top - 1e-3, top, top - fillet + fillet / np.sqrt(2) - 1e-6])
    d = rounded_cylinder_distance(rho, y, top, radius, fillet)
    assert d[:3] == pytest.approx([-4e-5, 1e-5, 2e-5], abs=1e-12)
    assert d[3] == pytest.approx((np.sqrt(2) - 1) * fillet, rel=1e-12)      # sharp corner: outside
    assert d[4] == pytest.approx(-1e-6 / np.sqrt(2), rel=3e-3)               # just inside the fillet


def test_the_rim_normal_is_the_gradient_of_the_signed_distance():
    """``rounded_cylinder_normal`` (the contact's n) against
    central differences of the tested distance, on the top face, the side wall and the fillet
    (away from the kinks between them); only fillet points are flagged as on the rim. Broken
    once (the fillet's n_y and n_ρ swapped): it failed."""
    from deapull.fem_solver.contact import rounded_cylinder_distance, rounded_cylinder_normal
    top, radius, fillet = 1.0e-3, 5e-3, 3e-4
    c_r, c_y = radius - fillet, top - fillet
    angles = np.radians([20.0, 60.0])
    rho = np.array([1e-3, radius + 1e-6, *(c_r + fillet * np.cos(angles))])
    y = np.array([top - 1e-6, top - 2e-3, *(c_y + fillet * np.sin(angles))])
    n_r, n_y, rim = rounded_cylinder_normal(rho, y, top, radius, fillet)
    h = 1e-9
    g_r = (rounded_cylinder_distance(rho + h, y, top, radius, fillet)
           - rounded_cylinder_distance(rho - h, y, top, radius, fillet)) / (2 * h)
    g_y = (rounded_cylinder_distance(rho, y + h, top, radius, fillet)
           - rounded_cylinder_distance(rho, y - h, top, radius, fillet)) / (2 * h)
    assert n_r == pytest.approx(g_r, abs=1e-5) and n_y == pytest.approx(g_y, abs=1e-5)
    assert list(rim) == [False, False, True, True]
    assert n_r[2:] == pytest.approx(np.cos(angles), abs=1e-5)


def test_static_balance_at_placement_checks_the_cone_without_inertia():
    """dt = 0 (the t = 0 record, no step): the balance is the static cone, |Fx| ≤ μ_b N."""
    rest = CoinState()
    inside = force_balance_residual(rest, rest, -0.9 * MU * M * G, 0.0, 0.0, M, MU, G)
    outside = force_balance_residual(rest, rest, -1.5 * MU * M * G, 0.0, 0.0, M, MU, G)
    assert inside == 0.0 and outside == pytest.approx(0.5 * MU * M * G, rel=1e-12)


def _curvature(rho, y, top, radius, rim, shape, h=1e-8):
    """div n of the rim's normal field (2D, (rho, y)) by central differences: the curvature of the
    level set through the point."""
    from deapull.geometry import rounded_cylinder_normal
    n_r = lambda r, yy: rounded_cylinder_normal(r, yy, top, radius, rim, shape)[0]  # noqa: E731
    n_y = lambda r, yy: rounded_cylinder_normal(r, yy, top, radius, rim, shape)[1]  # noqa: E731
    return (n_r(rho + h, y) - n_r(rho - h, y)) / (2 * h) + (n_y(rho, y + h) - n_y(rho, y - h)) / (2 * h)


def test_the_c2_rim_has_its_gap_normal_and_curvature_continuous_at_the_tangency():
    """The blended rim (coin.edge_shape = "c2") against the circular one, on the surface where
    the top face meets the rim (q_rho = 0, the tangency): the gap and the normal are continuous
    there for both (finite differences across it), and the curvature of the surface is too for
    the blend only (0 on the flat, -> 0 on the rim), while the circle's jumps to 1/r_f. Its normal
    is the gradient of its gap everywhere on the rim. Broken once with the blend's exponent 3 -> 2
    (a circle again): the curvature check failed."""
    from deapull.geometry import rounded_cylinder_distance, rounded_cylinder_normal
    top, radius, rim = 2.25e-3, 5e-3, 1e-3
    start = radius - rim                    # where the rim starts
    eps = np.array([1e-7, 1e-6, 1e-5])
    for shape in ("c2", "circular"):
        for y in (top, top + 2e-5):       # on the surface and 20 um above it
            d_in = rounded_cylinder_distance(start - eps, y, top, radius, rim, shape)
            d_out = rounded_cylinder_distance(start + eps, y, top, radius, rim, shape)
            assert np.all(np.abs(d_out - d_in) <= 2.1 * eps * 1e-2 + 1e-15)       # continuous, flat slope
            n_in = np.array(rounded_cylinder_normal(start - eps, y, top, radius, rim, shape)[:2])
            n_out = np.array(rounded_cylinder_normal(start + eps, y, top, radius, rim, shape)[:2])
            assert np.all(np.abs(n_out - n_in) <= 2.1 * eps / rim + 1e-12)        # the normal: continuous
    q = 1e-3 * rim                            # just onto the rim, on its surface
    on_c2 = _curvature(np.array([start + q]), np.array([top]), top, radius, rim, "c2")
    on_circle = _curvature(np.array([start + q]), np.array([top - q ** 2 / (2 * rim)]), top, radius, rim, "circular")
    flat = _curvature(np.array([start - q]), np.array([top]), top, radius, rim, "c2")
    assert abs(flat[0]) < 1.0 and abs(on_c2[0]) * rim < 0.01                     # ~0 on both sides
    assert on_circle[0] * rim == pytest.approx(1.0, rel=0.01)                    # the circle's jump
    # on the rim (45 degrees and near the side wall) the normal is the gap's gradient
    angle = np.radians([30.0, 45.0, 80.0])
    s = rim / np.cbrt(np.cos(angle) ** 3 + np.sin(angle) ** 3)          # on the superellipse
    rho, y = start + s * np.cos(angle), top - rim + s * np.sin(angle)
    h = 1e-9
    g_r = (rounded_cylinder_distance(rho + h, y, top, radius, rim, "c2")
           - rounded_cylinder_distance(rho - h, y, top, radius, rim, "c2")) / (2 * h)
    g_y = (rounded_cylinder_distance(rho, y + h, top, radius, rim, "c2")
           - rounded_cylinder_distance(rho, y - h, top, radius, rim, "c2")) / (2 * h)
    n_r, n_y, on_rim = rounded_cylinder_normal(rho, y, top, radius, rim, "c2")
    assert on_rim.all() and np.allclose(rounded_cylinder_distance(rho, y, top, radius, rim, "c2"), 0.0, atol=1e-15)
    assert n_r == pytest.approx(g_r, abs=1e-6) and n_y == pytest.approx(g_y, abs=1e-6)
