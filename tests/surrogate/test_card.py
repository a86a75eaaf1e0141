"""The model card: model.json says what a model was trained on, and a dataset that differs from it
is named."""
import json
import pytest
import xarray as xr

from deapull import dataset
from deapull.surrogate import card, store
from deapull.surrogate.data import load_setup


@pytest.fixture(scope="module")
def saved(tmp_path_factory, sweep, trained):
    result = trained("f-coulomb")
    folder = store.save(result.model, tmp_path_factory.mktemp("model") / "f", result.summary(), result.history)
    return folder, json.loads((folder / store.META).read_text())


def test_the_card_names_the_training_data_and_its_limits(saved, sweep):
    _, meta = saved
    c = meta["card"]
    assert c["training_coins"] == ["C1"] and c["validation_coins"] == ["C2"]
    assert c["datasets"]["C1"] == sweep["C1"].sha256 and len(c["datasets"]["C1"]) == 64
    # the test sweep is made with overrides of the shipped scene (tests/data/make_sweep.py)
    assert c["fidelity"] == "custom" and c["fidelity_id"] == sweep["C1"].fidelity_id != ""
    assert c["coins"]["coin_mass_kg"] == [sweep["C1"].mass_kg] * 2
    assert any(line.startswith("voltages outside [0, 400] V") for line in c["known_limits"])
    assert any("coins outside m_c in [1.36" in line for line in c["known_limits"])
    assert c["metrics"]["validation_x_error_pct_travel"] == pytest.approx(meta["training"]["val_x_error_pct"])


def test_a_dataset_that_differs_from_the_card_is_named(saved, sweep, tmp_path):
    _, meta = saved
    c = meta["card"]
    assert card.check(c, sweep["C1"]) == []                   # the training file itself
    # the same setup, re-made: the file differs
    with xr.open_dataset(sweep["C1"].path, engine=dataset.ENGINE) as ds:
        ds = ds.load()
    ds.attrs["wall_time_total_s"] = 1.0
    dataset.write(ds, tmp_path / "C1.nc")
    (message,) = card.check(c, load_setup(tmp_path / "C1.nc"))
    assert "not the file the model was trained on for C1" in message
    # another fidelity: a finer mesh in the run's scene
    ds.attrs["scene_toml"] = ds.attrs["scene_toml"].replace("[mesh]\n", "[mesh]\nlevel = 1\n", 1)
    dataset.write(ds, tmp_path / "C2.nc")
    messages = card.check(c, load_setup(tmp_path / "C2.nc"))
    assert any("made at fidelity 'custom'" in m and c["fidelity_id"] in m for m in messages)
    # another coin: outside the training box
    assert any("C8: coin m_c" in m and "extrapolates" in m for m in card.check(c, sweep["C8"]))
