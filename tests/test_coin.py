"""Coulomb block: the rigid coin under a prescribed force ramp against the closed-form solution."""
import numpy as np
import pytest

from fem_solver.coin import CoinState, coulomb_step, force_balance_residual

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
