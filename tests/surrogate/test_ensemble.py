"""The ensemble of restarts: a band calibrated on the validation run, repeats with their spread."""
import json

import numpy as np
import pytest

from deapull.surrogate import ensemble, experiments
from deapull.surrogate.train import TrainConfig, train


@pytest.fixture(scope="module")
def restarts(sweep):
    return train(TrainConfig(kind="f-coulomb", epochs=15, restarts=3), [sweep["C1"]], sweep["C2"])


def test_the_band_covers_its_level_of_the_validation_run_and_saves(restarts, sweep, tmp_path):
    members, val = restarts.members, sweep["C2"]
    assert len(members) == 3
    k = ensemble.calibrate(members, [val], restarts.phis)
    band = ensemble.band(members, k, val, members[0].phi_of(val))
    assert band.coverage(val.x) == pytest.approx(ensemble.LEVEL, abs=0.01)
    # the members disagree: the band is wider than its floor alone where the coin moves
    assert np.max(band.x.std(0)) > ensemble.FLOOR_SHARE * np.abs(band.mean).max()
    narrow = ensemble.band(members, 0.1 * k, val, members[0].phi_of(val))
    assert narrow.coverage(val.x) < band.coverage(val.x)
    ensemble.save(restarts, tmp_path / "m", k)
    again, k_again = ensemble.load(tmp_path / "m")
    assert k_again == k and json.loads((tmp_path / "m" / ensemble.CALIBRATION).read_text())["calibrated_on"] == ["C2"]
    assert np.array_equal(ensemble.band(again, k, val, again[0].phi_of(val)).upper, band.upper)


def test_experiments_repeat_with_new_seeds_and_report_the_spread_and_the_band(sweep_dir, tmp_path):
    rows = experiments.run(sweep_dir, tmp_path, TrainConfig(kind="f-coulomb", epochs=3), kinds=["f-coulomb", "nn"],
                           sets=[1], restarts={"f-coulomb": 2, "nn": 1}, repeats=2)
    seeds = {(r["repeat"], r["model"]): r["restart_seeds"] for r in rows}
    assert seeds == {(0, "f-coulomb"): "0;1", (1, "f-coulomb"): "2;3", (0, "nn"): "0", (1, "nn"): "1"}
    assert all(0 <= r["band_coverage"] <= 1 for r in rows if r["model"] == "f-coulomb")
    assert all(r["band_coverage"] is None for r in rows if r["model"] == "nn")
    assert (tmp_path / "set1" / "f-coulomb" / ensemble.CALIBRATION).is_file()
    assert (tmp_path / "repeats" / "1" / "set1" / "nn" / "model.json").is_file()
    table = (tmp_path / "table.txt").read_text()
    assert "mean ± std over 2 repeats" in table and "90 % band covers" in table
    x = [r["mae_x_m"] for r in rows if r["model"] == "f-coulomb"]
    mean, spread = experiments._mean_spread(rows, "f-coulomb", "mae_x_m")
    assert mean == pytest.approx(np.mean(x)) and spread == pytest.approx(np.std(x))


def test_held_out_pairs_trained_with_restarts_carry_a_band_on_every_held_out_run(sweep_dir, tmp_path):
    """The pair models (trained on the other coins, validated on one of them) keep their restarts'
    ensemble calibrated on the validation coin, and every held-out run gets its coverage: in the
    rows, pairs.json and pairs.md. The coverage is the band's own: the band built again from the
    saved members covers the same share of the run. Broken once with the ensemble not saved: no
    row had a coverage."""
    from deapull.surrogate import protocol_experiments as pe
    from deapull.surrogate.data import load_setup
    rows = pe.run_pairs(sweep_dir, tmp_path, TrainConfig(kind="f-coulomb", epochs=3, restarts=2), kinds=("f-coulomb",))
    assert rows and all(0 <= r["band_coverage"] <= 1 for r in rows)
    folder = tmp_path / "pair_C5_C6" / "f-coulomb"
    members, k = ensemble.load(folder)
    assert json.loads((folder / ensemble.CALIBRATION).read_text())["calibrated_on"] == ["C7"]
    run = load_setup(sweep_dir / "C5.nc")
    again = ensemble.band(members, k, run, members[0].phi_of(run)).coverage(run.x)
    assert next(r["band_coverage"] for r in rows if r["run"] == "C5") == pytest.approx(again)
    pairs = json.loads((tmp_path / "pairs.json").read_text())
    assert all(set(r["band_coverage"]) == {"f-coulomb"} for r in pairs["runs"])
    assert pairs["data"]["fidelity_id"] == [run.fidelity_id]          # the data it was made on
    assert "90 % band covers" in (tmp_path / "pairs.md").read_text()
