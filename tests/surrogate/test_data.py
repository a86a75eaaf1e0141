"""Datasets → transitions, and clear failures on bad datasets."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import xarray as xr

import deapull.dataset

from deapull.surrogate.data import DatasetError, load_setup, load_sweep, require_tip_contact, transitions
from deapull.surrogate.models import Normalisation
from deapull.surrogate.train import TrainConfig, train


def test_transitions_pair_each_state_with_the_next_increment(sweep):
    data = sweep["C1"]
    tr = transitions([data], window=8, dtype=torch.float64)
    assert len(tr) == data.n_steps - 1
    k = 100
    assert tr.s[k].tolist() == [data.x[k], data.u[k]]
    assert tr.a[k].tolist() == [data.V[k + 1], data.dt[k + 1]]
    assert tr.z[k].tolist() == [data.Fx[k + 1], data.Fy[k + 1]]
    assert tr.s_next[k].tolist() == [data.x[k + 1], data.u[k + 1]]
    assert tr.phi.mass_kg[k].item() == data.mass_kg and tr.phi.mu_b[k].item() == data.mu_b
    assert math.isnan(tr.phi.v_threshold_V[k]), "no V^T unless the kind asks for it"
    assert tr.phi.mu_t[k].item() == data.mu_t == 0.5 and tr.v_prev[k].item() == data.V[k]
    assert tr.phi.mass_kg.shape == (len(tr),) and tr.subset(torch.tensor([k])).phi.mu_t.tolist() == [0.5]
    assert tr.window.shape == (len(tr), 8, 4)
    assert torch.equal(tr.window[k, -1], torch.cat([tr.s[k], tr.a[k]]))
    assert torch.equal(tr.window[k, 0], torch.cat([tr.s[k - 7], tr.a[k - 7]]))
    assert torch.equal(tr.window[0], tr.window[0, :1].expand(8, 4)), "the start is padded with the first pair"


def test_two_stages_threshold_and_contact(sweep):
    for data in sweep.values():
        vt = data.threshold_voltage()
        assert 50 < vt < 350
        assert np.all(data.x[data.V < 0.9 * vt] == 0), "static stage: the coin does not move"
        assert data.travel_m >= 3e-4    # test-size mesh: 0.47-0.69 mm (shipped mesh: >= 1.09 mm)
        assert data.contact_loss_voltage() == math.inf


def test_contact_loss_voltage_found(sweep_dir, tmp_path):
    with xr.open_dataset(sweep_dir / "C1.nc", engine="h5netcdf") as ds:
        ds = ds.load()
    lost = ds["V"].values >= 300
    for name in ("Fx", "Fy"):
        ds[name].values[lost] = 0.0
    ds.to_netcdf(tmp_path / "C1.nc", engine="h5netcdf")
    data = load_setup(tmp_path / "C1.nc")
    assert data.contact_loss_voltage() == pytest.approx(data.V[np.argmax(lost)])


def test_normalisation_scales_are_positive(sweep):
    norm = Normalisation.from_transitions(transitions([sweep["C1"]], 1))
    for values in (norm.in_std, norm.z_std, norm.s_std, norm.ds_std):
        assert all(v > 0 for v in values)


def _corrupt(sweep_dir, tmp_path, edit):
    with xr.open_dataset(sweep_dir / "C3.nc", engine="h5netcdf") as ds:
        ds = ds.load()
    ds = edit(ds) or ds
    path = tmp_path / "C3.nc"
    ds.to_netcdf(path, engine="h5netcdf")
    return path


def _set_nan(ds):
    ds["u"].values[42] = np.nan


def _set_units(ds):
    ds["Fx"].attrs["units"] = "mN"


def _drop(ds):
    return ds.drop_vars("Fy")


def _incomplete(ds):
    ds.attrs["complete"] = 0


def _no_mass(ds):
    del ds.attrs["coin_mass_kg"]


def _negative_mu_t(ds):
    ds.attrs["coin_mu_t"] = -0.5


def _short(ds):
    return ds.isel(step=slice(0, 9))


def _zero_step(ds):
    ds["dt"].values[5] = 0.0


def _transposed(ds):
    return ds.assign(x=(("step", "two"), np.stack([ds["x"].values] * 2, axis=1), ds["x"].attrs))


@pytest.mark.parametrize("edit, words", [
    (_drop, ["'Fy'", "missing"]),
    (_set_units, ["'Fx'", "'mN'", "'N'"]),
    (_set_nan, ["'u'", "non-finite", "step 42"]),
    (_incomplete, ["'complete'"]),
    (_no_mass, ["'coin_mass_kg'", "missing"]),
    (_negative_mu_t, ["'coin_mu_t'", "-0.5", "non-negative"]),
    (_short, ["'t'", "9 steps", "at least 10"]),
    (_zero_step, ["'dt'", "non-positive", "step 5"]),
    (_transposed, ["'x'", "dimensions"]),
])
def test_bad_dataset_fails_naming_file_and_variable(sweep_dir, tmp_path, edit, words):
    path = _corrupt(sweep_dir, tmp_path, edit)
    with pytest.raises(DatasetError) as err:
        load_setup(path)
    assert isinstance(err.value, ValueError) and isinstance(err.value, deapull.dataset.DatasetError)
    assert str(path) in str(err.value)
    for word in words:
        assert word in str(err.value)


def test_missing_file_and_folder(sweep_dir, tmp_path):
    with pytest.raises(DatasetError, match="C9.nc"):
        load_sweep(sweep_dir, ["C1", "C9"])
    with pytest.raises(DatasetError, match="no such data folder"):
        load_sweep(tmp_path / "nowhere", ["C1"])


def test_dataset_without_the_tip_contact_attributes_is_refused_by_f_coulomb(sweep_dir, tmp_path):
    def old(ds):
        del ds.attrs["contact_slip_rate_reg_m_s"]
    data = load_setup(_corrupt(sweep_dir, tmp_path, old))
    assert math.isnan(data.slip_rate_reg_m_s)
    with pytest.raises(DatasetError, match="'contact_slip_rate_reg_m_s' is missing.*rerun the sweep"):
        require_tip_contact(data)
    with pytest.raises(DatasetError, match="'contact_slip_rate_reg_m_s'"):
        train(TrainConfig(kind="f-coulomb", epochs=1), [data], data)


def test_coin_that_never_moves_has_no_threshold(sweep_dir, tmp_path):
    def still(ds):
        ds["x"].values[:] = 0.0
    path = _corrupt(sweep_dir, tmp_path, still)
    with pytest.raises(DatasetError, match="'x'.*V\\^T"):
        load_setup(path).threshold_voltage()
