"""scripts/patch_probe.py (the patch-probe diagnostic of docs/surrogate.md) on synthetic coins
under one patch of a known friction-speed curve: the points' x speeds spread uniformly over
[(1 - s) v, (1 + s) v], so a coin of margin r = mu_b N / (mu_t Fy) < 1 moves at c = 1 - s r."""
import importlib.util

import numpy as np
import pytest

from deapull import dataset
from tests.conftest import REPO

spec = importlib.util.spec_from_file_location("patch_probe", REPO / "scripts" / "patch_probe.py")
patch_probe = importlib.util.module_from_spec(spec)
spec.loader.exec_module(patch_probe)

SPREAD = 0.25


def coin(mass, mu_t, mu_b, spread=SPREAD):
    """A 1 s ramp under the uniform-spread patch (speed 3.4 t mm/s toward -x, Fy rising), with
    the probe's columns as the FEM records them and x(t) from c = 1 - s r (trapezoids)."""
    t = np.linspace(0.0, 1.0, 2001)
    vx, fy = -3.4e-3 * t, 0.005 + 0.035 * t
    c = np.asarray(dataset.PATCH_SHARES)
    drag = -fy[:, None] * np.clip((1 - c[None, :]) / spread, -1.0, 1.0)     # pulls toward -x
    r = mu_b * (mass * patch_probe.G + fy) / (mu_t * fy)
    u = np.where(r < 1, (1 - spread * r) * vx, 0.0)
    x = np.concatenate([[0.0], np.cumsum(0.5 * (u[1:] + u[:-1]) * np.diff(t))])
    return dict(t=t, V=400 * t, x=x, u=u, Fy=fy, patch_vx=vx, patch_normal_x=np.zeros_like(t), drag=drag,
                m=mass, mu_t=mu_t, mu_b=mu_b)


def test_a_patch_of_the_voltage_alone_carries_one_coin_to_another():
    """The training coin's patch predicts a rougher coin under the same patch to the time step,
    and a wider patch (a coin-dependent one) misses it. Broken once (the drag's sign flipped in
    the balance, f = N_x - mu_t D): this test and the next failed."""
    train, test = coin(1.36e-3, 0.55, 0.20), coin(1.36e-3, 0.50, 0.25)
    assert abs(test["x"][-1]) < 0.9 * abs(train["x"][-1])            # the rougher coin goes less far
    for patch in (train, test):
        mae, travel = patch_probe.errors(patch, test)
        assert mae < 0.1 and abs(travel) < 0.1                       # % of travel; measured 0.025 and 0.054
    mae, travel = patch_probe.errors(coin(1.36e-3, 0.55, 0.20, spread=0.5), test)
    assert mae > 2 and travel < -5


def test_the_share_sticks_the_coin_where_the_patch_cannot_beat_the_ground():
    drag = -np.ones(len(dataset.PATCH_SHARES)) * 0.01
    assert patch_probe.share(0.0, drag, 0.5, 0.006) == 0.0             # mu_t D(0) = -0.005 > -0.006
    assert patch_probe.share(0.002, drag, 0.5, 0.004) == 0.0           # the rim's push tips it over
    assert patch_probe.share(0.0, drag, 0.5, 0.004) == pytest.approx(dataset.PATCH_SHARES[-1])

