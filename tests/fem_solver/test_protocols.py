"""The FEM under protocols beyond the ramp: the release pulls the coin toward the clamp, and
the stepper lands on a protocol's kinks."""
import numpy as np
import xarray as xr

from deapull import protocol, scene as scenes
from deapull.fem_solver.run import solve_scene
from tests.conftest import SHARP

TEST_MESH = (*SHARP, "mesh.n_length=8", "mesh.n_width=1", "mesh.coin_size_m=0.004")


def test_release_pulls_the_coin_toward_the_clamp(tmp_path):
    """coin_release: placed on the coin at 400 V, then 400 -> 0 V. A static stage first (the
    coin holds while the tip's friction is inside the ground's cone), then the retracting tip
    drags the coin toward +x (measured on this mesh over 1 s: 0.72 mm, sliding from 348 V)."""
    sc = scenes.load("coin_release", setup="C3", overrides=(*TEST_MESH, "load.ramp_time_s=0.4",
                                                              "load.end_time_s=0.4", "time.dt_max_s=0.01"))
    with xr.open_dataset(solve_scene(sc, tmp_path, progress=False)) as ds:
        x, V, stick = ds.x.values, ds.V.values, ds.stick.values
        assert V[0] == 400 and V[-1] == 0 and ds.attrs["load_protocol"] == "release"
        assert x.min() >= 0 and x.max() > 0.3e-3, x.max()          # toward the clamp, a real distance
        assert stick[:3].all() and np.all(x[:3] == 0)                 # the static stage comes first
        assert ds.attrs["coin_motion"] == "toward +x (toward the clamp)"
        assert ds.attrs["coin_travel_m"] == x.max()


def test_run_lands_on_the_kinks_of_a_table_protocol(tmp_path):
    sc = scenes.load("coin_pull", setup="C3", overrides=(
        *TEST_MESH, "load.protocol='table'", "load.table_t_s=[0, 0.0123, 0.02, 0.03]", "load.table_V=[0, 120, 120, 60]",
        "load.end_time_s=0.03", "time.dt_max_s=0.004", "time.dt_initial_s=0.004"))
    with xr.open_dataset(solve_scene(sc, tmp_path, progress=False)) as ds:
        t, V = ds.t.values, ds.V.values
    for kink in (0.0123, 0.02):
        i = int(np.argmin(abs(t - kink)))
        assert abs(t[i] - kink) < 1e-12, (kink, t)
    expected = [protocol.from_load(sc.load).voltage(ti) for ti in t]
    assert np.allclose(V, expected, rtol=0, atol=1e-9)
    assert V.max() == 120 and V[-1] == 60
