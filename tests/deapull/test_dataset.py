"""The dataset contract: what the writer refuses, what a reader is told, and atomic writes."""
import numpy as np
import pytest

from deapull import dataset
from deapull.io import atomic_write, write_csv


def columns(n=12):
    cols = {name: np.linspace(0, 1, n) for name in dataset.VARIABLES}
    cols["x"] = -1e-4 * cols["t"]
    return cols


ATTRS = {"coin_mass_kg": 1.36e-3, "coin_mu_b": 0.2, "gravity_m_s2": 9.8, "setup": "C9"}


def test_build_write_read_round_trip(tmp_path):
    path = dataset.write(dataset.build(columns(), ATTRS), tmp_path / "C9.nc")
    assert dataset.is_complete(path)
    run = dataset.read(path, variables=("t", "x", "Fy"))
    assert np.array_equal(run.columns["x"], columns()["x"]) and run.number("coin_mass_kg") == 1.36e-3
    for name, (units, long_name) in dataset.VARIABLES.items():
        assert units and long_name, name


def test_writer_refuses_nan_and_a_foreign_column():
    bad = columns()
    bad["Fx"][3] = np.nan
    with pytest.raises(ValueError, match="'Fx' has non-finite values"):
        dataset.build(bad, ATTRS)
    extra = {**columns(), "temperature": np.zeros(12)}
    with pytest.raises(ValueError, match="unknown \\['temperature'\\]"):
        dataset.build(extra, ATTRS)


@pytest.mark.parametrize("edit, words", [
    (lambda ds: ds.drop_vars("Fy"), "variable 'Fy' is missing"),
    (lambda ds: ds.assign(x=ds.x.assign_attrs(units="mm")), "variable 'x' has units 'mm', expected 'm'"),
    (lambda ds: ds.assign(u=ds.u.where(ds.step != 4)), "variable 'u' has a non-finite value (nan) at step 4"),
    (lambda ds: ds.assign_attrs(complete=0), "attribute 'complete' is not 1"),
])
def test_reader_names_the_file_and_the_variable(tmp_path, edit, words):
    path = tmp_path / "bad.nc"
    edit(dataset.build(columns(), ATTRS)).to_netcdf(path, engine=dataset.ENGINE)
    with pytest.raises(dataset.DatasetError) as err:
        dataset.read(path, variables=("t", "x", "u", "Fy"))
    assert str(path) in str(err.value) and words in str(err.value)


def test_reader_attribute_checks(tmp_path):
    path = dataset.write(dataset.build(columns(), {**ATTRS, "coin_mu_b": -0.2}), tmp_path / "a.nc")
    run = dataset.read(path)
    with pytest.raises(dataset.DatasetError, match="attribute 'coin_mu_b' = -0.2 must be a non-negative"):
        run.number("coin_mu_b", positive=False)
    with pytest.raises(dataset.DatasetError, match="attribute 'coin_mu_t' is missing"):
        run.number("coin_mu_t")
    assert run.number("coin_mu_t", default=float("inf")) == float("inf")
    with pytest.raises(dataset.DatasetError, match="no such dataset file"):
        dataset.read(tmp_path / "none.nc")


def test_atomic_write_leaves_nothing_when_the_writer_fails(tmp_path):
    target = tmp_path / "sub" / "out.csv"
    write_csv(target, [{"a": 1, "b": [1, 2]}], ["a", "b"])
    before = target.read_text()
    assert before == "a,b\n1,1 2\n"

    def broken(tmp):
        open(tmp, "w").write("half")
        raise RuntimeError("disk full")
    with pytest.raises(RuntimeError):
        atomic_write(target, broken)
    assert target.read_text() == before and sorted(p.name for p in target.parent.iterdir()) == ["out.csv"]
