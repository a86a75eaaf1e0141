"""The ``deapull train | evaluate | experiments`` sub-commands on the test sweep (the
committed FEM fixture of tests/data/sweep; no FEniCSx needed)."""
from __future__ import annotations

import argparse
import csv
import json
import re

import numpy as np
import pytest
import xarray as xr

from deapull.errors import InputError
from deapull.surrogate.data import DatasetError
from deapull.workflows import cli_surrogate as cli

pytestmark = pytest.mark.filterwarnings("ignore::deapull.surrogate.rollout.OutOfRangeWarning")


def _run(*argv: str) -> int:
    parser = argparse.ArgumentParser(prog="deapull")
    cli.register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


def _fem(path) -> dict:
    """A dataset's arrays and attributes, read with xarray alone (not the surrogate's reader)."""
    with xr.open_dataset(path, engine="h5netcdf") as ds:
        return {**{k: ds[k].values.astype(float) for k in ("x", "u", "Fx", "Fy")}, "attrs": dict(ds.attrs)}


def test_train_then_evaluate_round_trip(sweep_dir, tmp_path, capsys):
    """Train, then give the model a known answer and check ``evaluate``'s numbers against it.

    With the last layer of m zeroed, the tip-contact model's stroke is 0 at every voltage
    and its pressing force is the training data's mean Fy: the tip never moves, so the coin
    stays at rest and the tip exerts no friction. Every error is then a statistic of the FEM
    run alone, computed here with numpy: MAE x = mean |x|, MAE Fx = mean |Fx|, MAE Fy =
    mean |Fy - mean Fy of C1| (over the transitions), and so on."""
    import torch
    out = tmp_path / "model"
    assert _run("train", "--data", str(sweep_dir), "--train", "C1", "--val", "C2", "--model", "f-coulomb",
                "--out", str(out), "--epochs", "5", "--seed", "3", "--restarts", "2") == 0
    assert {p.name for p in out.iterdir()} >= {"model.pt", "model.json", "history.csv"}
    meta = json.loads((out / "model.json").read_text())
    assert meta["kind"] == "f-coulomb" and meta["training"]["config"]["seed"] == 3
    restarts = meta["training"]["restarts"]   # every restart's validation score and the kept seed
    assert [r["seed"] for r in restarts] == [3, 4] and meta["training"]["config"]["restarts"] == 2
    kept = min(restarts, key=lambda r: r["val_x_error_pct"])
    assert meta["training"]["selected_seed"] == kept["seed"] and [r["kept"] for r in restarts] == [
        r is kept for r in restarts]
    assert f"kept seed {kept['seed']} of 2" in capsys.readouterr().out
    assert set(meta["training"]["setups"]) == {"C1", "C2"}
    assert meta["input_range"]["inputs"] == ["x", "u", "V", "dt"]
    state = torch.load(out / "model.pt", weights_only=True)
    last = max(int(k.split(".")[1]) for k in state if k.startswith("material."))
    for k in (f"material.{last}.weight", f"material.{last}.bias"):
        state[k].zero_()
    torch.save(state, out / "model.pt")

    assert _run("evaluate", "--model", str(out), "--data", str(sweep_dir), "--test", "C3") == 0
    printed = capsys.readouterr().out
    assert "MAE x" in printed and "C3" in printed
    result = json.loads((out / "evaluate_C3.json").read_text())
    c1, c3 = _fem(sweep_dir / "C1.nc"), _fem(sweep_dir / "C3.nc")
    x, travel = c3["x"][1:], np.abs(c3["x"]).max()
    expected = {"mae_x_m": np.abs(x).mean(), "mae_u_m_s": np.abs(c3["u"][1:]).mean(),
                "mae_Fx_N": np.abs(c3["Fx"][1:]).mean(), "mae_Fy_N": np.abs(c3["Fy"][1:] - c1["Fy"][1:].mean()).mean(),
                "max_abs_x_error_m": np.abs(x).max(), "final_x_error_m": -x[-1],
                "x_error_pct_travel": 100 * np.abs(x).mean() / travel, "travel_m": travel}
    for key, value in expected.items():
        assert result[key] == pytest.approx(value, rel=1e-5), key
    assert result["steps"] == len(x) and not result["diverged"]
    assert result["phi"] == {"mass_kg": c3["attrs"]["coin_mass_kg"], "mu_b": c3["attrs"]["coin_mu_b"],
                             "mu_t": c3["attrs"]["coin_mu_t"]}, "the test coin, C3's"
    assert result["setup"] == "C3" and result["trained_on"]["C1"]["role"] == "train"


def _table(text: str) -> dict:
    """Table II of table.txt as {row label: {column header: cell}}."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("mean over sets"))
    head = re.split(r"\s{2,}", lines[start].strip())
    rows = {}
    for line in lines[start + 1:]:
        if not line.strip():
            break
        cells = re.split(r"\s{2,}", line.strip())
        rows[cells[0]] = dict(zip(head[1:], cells[1:]))
    return rows


def test_restarts_per_model_kind(sweep_dir, tmp_path):
    from deapull.workflows.cli_surrogate import RESTARTS, parse_restarts
    assert parse_restarts("3") == (3, {})
    assert parse_restarts("f-coulomb=2, nn=4") == (1, {"f-coulomb": 2, "nn": 4})
    assert parse_restarts(RESTARTS)[0] == 1     # the default: named kinds only, the rest once
    for bad in ("0", "f=0", "f=1.5", "f=", "x"):
        with pytest.raises(InputError, match=r"--restarts .*must be a whole number of at least 1"):
            parse_restarts(bad)
    with pytest.raises(InputError, match=r"--repeats 0: must be a whole number of at least 1"):
        _run("experiments", "--data", str(tmp_path / "none"), "--out", str(tmp_path / "e"), "--repeats", "0")
    assert not (tmp_path / "e").exists()
    with pytest.raises(InputError, match=r"--restarts lstmm=2: lstmm is not a model"):
        _run("experiments", "--data", str(tmp_path / "none"), "--out", str(tmp_path / "e"), "--restarts", "lstmm=2")
    out = tmp_path / "exp"
    assert _run("experiments", "--data", str(sweep_dir), "--out", str(out), "--epochs", "2", "--sets", "1",
                "--models", "f-coulomb,nn", "--restarts", "f-coulomb=2", "--repeats", "1") == 0
    with open(out / "experiments.csv") as fh:
        restarts = {r["model"]: r["restarts"] for r in csv.DictReader(fh)}
    assert restarts == {"f-coulomb": "2", "nn": "1"}


def test_experiments_write_table_csv_and_plots(sweep_dir, tmp_path, capsys):
    out = tmp_path / "exp"
    assert _run("experiments", "--data", str(sweep_dir), "--out", str(out), "--epochs", "2", "--sets", "1,2",
                "--models", "f,f-coulomb,nn", "--restarts", "2", "--repeats", "1") == 0
    with open(out / "experiments.csv") as fh:
        rows = list(csv.DictReader(fh))
    json_rows = json.loads((out / "experiments.json").read_text())["rows"]
    for r, jr in zip(rows, json_rows):   # the kept seed: the lower validation rollout error, from the model too
        scores = [float(v) for v in r["restart_val_x_error_pct"].split(";")]   # inf: the rollout diverged
        losses = [float(v) for v in r["restart_val_loss"].split(";")]
        assert r["restarts"] == "2" and r["restart_seeds"] == "0;1" and len(scores) == len(losses) == 2
        kept = min(range(2), key=lambda k: (scores[k], losses[k]))   # the lower score, then the lower loss
        assert int(r["seed"]) == kept == jr["seed"]
        if np.isfinite(scores[kept]):
            assert float(r["val_x_error_pct_travel"]) == pytest.approx(scores[kept], rel=1e-5)
        else:
            assert r["val_x_error_pct_travel"] == "" and jr["val_x_error_pct_travel"] is None
        meta = json.loads((out / f"set{r['set']}" / r["model"] / "model.json").read_text())["training"]
        assert meta["selected_seed"] == int(r["seed"])
        assert [x["val_x_error_pct"] if x["val_x_error_pct"] is not None else np.inf
                for x in meta["restarts"]] == pytest.approx(scores, rel=1e-5)
    assert [(r["set"], r["model"], r["test"]) for r in rows] == [(s, m, t) for s, t in (("1", "C3"), ("2", "C4"))
                                                                 for m in ("f", "f-coulomb", "nn")]
    for r in rows:   # the FEM side of each row, against the test file read here
        fem = _fem(sweep_dir / f"{r['test']}.nc")
        assert float(r["travel_m"]) == pytest.approx(np.abs(fem["x"]).max(), rel=1e-12)
    # Table II: the paper's numbers in their rows and columns, ours the mean of the CSV's rows
    table = _table((out / "table.txt").read_text())
    paper_f, paper_nn = "paper f (paper law)", "paper NN"
    assert (table["MAE x [1e-4 m]"][paper_f], table["MAE x [1e-4 m]"][paper_nn]) == ("0.34", "9.86")
    assert (table["MAE Fx [1e-4 N]"][paper_f], table["MAE Fy [1e-4 N]"][paper_f]) == ("3.68", "12")
    assert (table["MAE Fy [1e-4 N]"][paper_nn], table["rollout [ms]"][paper_nn]) == ("-", "300")
    assert "paper f (tip contact)" not in table["MAE x [1e-4 m]"], "the paper has no tip-contact model"
    for kind, label in (("f", "f (paper law)"), ("f-coulomb", "f (tip contact)"), ("nn", "NN")):
        mine = [r for r in rows if r["model"] == kind]
        finished = [float(r["mae_x_m"]) for r in mine if r["diverged"] == "False"]
        assert table["diverged rollouts"][label] == str(len(mine) - len(finished))
        assert table["MAE x [1e-4 m]"][label] == (f"{np.mean(finished) / 1e-4:.3g}" if finished else "-"), kind
    assert table["diverged rollouts"]["f (tip contact)"] == "0", "two epochs of the tip-contact model do not diverge"
    for png in ("x_error_boxplot.png", "rollouts.png"):
        assert (out / png).read_bytes()[:4] == b"\x89PNG"
    assert (out / "set2" / "nn" / "model.pt").is_file()
    assert "MAE x" in capsys.readouterr().out


def test_bad_input_is_a_clear_value_error(sweep_dir, tmp_path):
    with pytest.raises(DatasetError, match="C9.nc"):
        _run("train", "--data", str(sweep_dir), "--train", "C1", "--val", "C9", "--model", "nn", "--out",
             str(tmp_path / "m"))
    with pytest.raises(InputError, match="model.json"):
        _run("evaluate", "--model", str(tmp_path / "nothing"), "--data", str(sweep_dir), "--test", "C3")
    with pytest.raises(InputError, match="set 7"):
        _run("experiments", "--data", str(sweep_dir), "--out", str(tmp_path / "e"), "--sets", "7")
    # refused before any data is read (the folder does not exist) or any model trained
    with pytest.raises(InputError, match=r"--restarts 0: must be a whole number of at least 1"):
        _run("train", "--data", str(tmp_path / "none"), "--train", "C1", "--val", "C2", "--model", "nn",
             "--out", str(tmp_path / "m"), "--restarts", "0")
    with pytest.raises(InputError, match=r"--restarts -3: must be a whole number of at least 1"):
        _run("experiments", "--data", str(tmp_path / "none"), "--out", str(tmp_path / "e"), "--restarts", "-3")
    assert not (tmp_path / "m").exists() and not (tmp_path / "e").exists()
    assert issubclass(InputError, ValueError)


def test_deapull_entry_point_maps_bad_input_to_exit_2(sweep_dir, tmp_path, capsys):
    from deapull.workflows.cli import main
    code = main(["train", "--data", str(sweep_dir), "--train", "C1", "--val", "C9", "--model", "nn",
                 "--out", str(tmp_path / "m")])
    assert code == 2
    assert "C9.nc" in capsys.readouterr().err


def _with_slip_rate_reg(src, dst, eps):
    import h5py                 # Debian's (the dolfinx one) or PyPI's: either reads the file's root attributes
    dst.write_bytes(src.read_bytes())
    with h5py.File(dst, "r+") as f:
        f.attrs["contact_slip_rate_reg_m_s"] = np.array([eps])


def test_f_coulomb_takes_the_ramps_friction_regularisation_and_trains_on_extra_runs_at_another(sweep_dir, tmp_path,
                                                                                               caplog):
    """The push set is solved at a wider ε_v than the ramps: f-coulomb keeps the ramps' ε_v and says so for
    the extra run; two ramps of different ε_v are still refused."""
    runs = tmp_path / "runs"
    runs.mkdir()
    _with_slip_rate_reg(sweep_dir / "C1.nc", runs / "C1_push.nc", 1e-3)
    out = tmp_path / "m"
    with caplog.at_level("WARNING"):
        assert _run("train", "--data", str(sweep_dir), "--train", "C1", "--val", "C2", "--model", "f-coulomb",
                    "--out", str(out), "--epochs", "1", "--restarts", "1", "--runs", str(runs)) == 0
    assert json.loads((out / "model.json").read_text())["hyper_parameters"]["slip_rate_reg_m_s"] == 1e-4
    assert "extra runs C1_push were made at another friction regularisation" in caplog.text
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    for name in ("C1", "C3"):
        (mixed / f"{name}.nc").write_bytes((sweep_dir / f"{name}.nc").read_bytes())
    _with_slip_rate_reg(sweep_dir / "C2.nc", mixed / "C2.nc", 1e-3)
    with pytest.raises(InputError, match=r"different friction regularisations \[0.0001, 0.001\] m/s"):
        _run("train", "--data", str(mixed), "--train", "C1,C2", "--val", "C3", "--model", "f-coulomb",
             "--out", str(tmp_path / "refused"), "--epochs", "1", "--restarts", "1")


def test_train_takes_further_runs_of_its_coins_with_the_coins_phi(sweep_dir, tmp_path):
    """``--runs DIR``: the runs ``<setup>_<name>.nc`` of the training setups join the training, the
    validation setup's the validation, each with its setup's φ (here a copy of C3's ramp filed as a
    run of C1 gets C1's threshold voltage V^T, not C3's); a folder without a run of a training
    setup is refused before any model is trained."""
    runs = tmp_path / "runs"
    runs.mkdir()
    (runs / "C1_other.nc").write_bytes((sweep_dir / "C3.nc").read_bytes())
    (runs / "C2_other.nc").write_bytes((sweep_dir / "C2.nc").read_bytes())
    (runs / "C4_other.nc").write_bytes((sweep_dir / "C4.nc").read_bytes())    # neither trained nor validated
    out = tmp_path / "m"
    assert _run("train", "--data", str(sweep_dir), "--train", "C1", "--val", "C2", "--model", "f", "--out", str(out),
                "--epochs", "2", "--restarts", "1", "--runs", str(runs)) == 0
    setups = json.loads((out / "model.json").read_text())["training"]["setups"]
    assert {name: s["role"] for name, s in setups.items()} == {"C1": "train", "C1_other": "train", "C2": "val",
                                                                 "C2_other": "val"}
    assert setups["C1_other"]["v_threshold_V"] == setups["C1"]["v_threshold_V"]
    assert setups["C1_other"]["steps"] == _fem(sweep_dir / "C3.nc")["x"].size
    alone = tmp_path / "alone"
    assert _run("train", "--data", str(sweep_dir), "--train", "C3", "--val", "C2", "--model", "f", "--out",
                str(alone), "--epochs", "2", "--restarts", "1") == 0
    assert json.loads((alone / "model.json").read_text())["training"]["setups"]["C3"]["v_threshold_V"] != \
        setups["C1_other"]["v_threshold_V"], "the fixture's C1 and C3 thresholds must differ for the check above"
    for folder, match in ((tmp_path / "none", r"--runs .*none: no such folder"),
                          (runs, r"--runs .*runs: no run of the training setups C5 \(files named <setup>_<name>.nc")):
        with pytest.raises(InputError, match=match):
            _run("train", "--data", str(sweep_dir), "--train", "C5", "--val", "C2", "--model", "f", "--out",
                 str(tmp_path / "refused"), "--runs", str(folder))
    again = tmp_path / "again"
    again.mkdir()
    (again / "C1_other.nc").write_bytes((sweep_dir / "C1.nc").read_bytes())
    with pytest.raises(InputError, match=r"--runs: the run C1_other is in more than one folder"):
        _run("train", "--data", str(sweep_dir), "--train", "C1", "--val", "C2", "--model", "f", "--out",
             str(tmp_path / "refused"), "--runs", str(runs), "--runs", str(again))
    assert not (tmp_path / "refused").exists()
