"""scripts/effective_slip.py (the sideways-slip diagnostic of docs/surrogate.md) on two synthetic
coins that obey its law exactly: a point contact whose slip has a constant sideways part w_z."""
import importlib.util

import numpy as np
import pytest

from tests.conftest import REPO

spec = importlib.util.spec_from_file_location("effective_slip", REPO / "scripts" / "effective_slip.py")
effective_slip = importlib.util.module_from_spec(spec)
spec.loader.exec_module(effective_slip)

WZ = 1e-3    # m/s


def coin(mass, mu_t, mu_b):
    """A 1 s ramp: tip stroke c t^2, Fy rising; the coin slides where mu_t Fy cos(theta) beats the
    ground at u = 0, at the speed where (w - u) / |(w - u, w_z)| = mu_b N / (mu_t Fy)."""
    t = np.linspace(0.0, 1.0, 1001)
    tip_ux = -1.7e-3 * t ** 2
    w = np.gradient(-tip_ux, t)
    fy = 0.005 + 0.035 * t
    need = mu_b * (mass * effective_slip.G + fy) / (mu_t * fy)
    slides = (need < 1) & (w / np.sqrt(w * w + WZ * WZ) > need)
    u = np.where(slides, w - WZ * need / np.sqrt(np.clip(1 - need * need, 1e-12, None)), 0.0)
    x = -np.concatenate([[0.0], np.cumsum(0.5 * (u[1:] + u[:-1]) * np.diff(t))])
    fx = np.where(slides, -mu_b * (mass * effective_slip.G + fy), -0.5 * mu_b * mass * effective_slip.G)
    return dict(t=t, V=400.0 * t, x=x, u=-u, Fx=fx, Fy=fy, tip_ux=tip_ux, w=w, m=mass, mu_t=mu_t, mu_b=mu_b)


def test_the_sideways_slip_read_off_one_coin_predicts_another():
    """w_z read off the training coin (from its u, Fx, Fy and tip speed) predicts a rougher coin of
    the same law to round-off, while the tip carrying the coin misses it by far; the read-off w_z
    is the law's. Broken once: w_z = (w - u) r / sqrt(1 - r^2) (the ratio inverted): the read-off
    w_z check failed."""
    train, test = coin(1.36e-3, 0.55, 0.20), coin(1.36e-3, 0.50, 0.25)
    assert -test["x"][-1] < 0.9 * -train["x"][-1]          # the rougher coin goes less far
    sliding = -train["u"] > 1e-5
    np.testing.assert_allclose(effective_slip.sideways_slip(train)(train["V"][sliding]), WZ, rtol=1e-6)
    mae, travel = effective_slip.predict(train, test, carried=False)
    assert mae < 0.05 and abs(travel) < 0.05               # % of travel
    mae_carried, travel_carried = effective_slip.predict(train, test, carried=True)
    assert mae_carried > 5 and travel_carried > 10


@pytest.mark.parametrize("script", ["effective_slip", "patch_probe"])
def test_a_data_folder_without_the_sweep_is_refused_naming_the_files(tmp_path, capsys, script):
    """Both sweep diagnostics (scripts/effective_slip.py, scripts/patch_probe.py)."""
    spec = importlib.util.spec_from_file_location(script, REPO / "scripts" / f"{script}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    (tmp_path / "C1.nc").write_bytes(b"")
    with pytest.raises(SystemExit) as exit_:
        module.main(["--data", str(tmp_path)])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert "C2.nc" in err and "C8.nc" in err and "C1.nc," not in err and "make sweep" in err
