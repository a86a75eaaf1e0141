"""The ``deapull train | evaluate | experiments`` sub-commands on the test sweep."""
from __future__ import annotations

import argparse
import csv
import json

import pytest

from surrogate import cli
from surrogate.data import DatasetError
from workflows.errors import InputError


def _run(*argv: str) -> int:
    parser = argparse.ArgumentParser(prog="deapull")
    cli.register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


def test_train_then_evaluate_round_trip(sweep_dir, tmp_path, capsys):
    out = tmp_path / "model"
    assert _run("train", "--data", str(sweep_dir), "--train", "C1", "--val", "C2", "--model", "f-coulomb",
                "--out", str(out), "--epochs", "5", "--seed", "3") == 0
    assert {p.name for p in out.iterdir()} >= {"model.pt", "model.json", "history.csv"}
    meta = json.loads((out / "model.json").read_text())
    assert meta["kind"] == "f-coulomb" and meta["training"]["config"]["seed"] == 3
    assert set(meta["training"]["setups"]) == {"C1", "C2"}
    assert meta["input_range"]["inputs"] == ["x", "u", "V", "dt"]
    assert _run("evaluate", "--model", str(out), "--data", str(sweep_dir), "--test", "C3") == 0
    printed = capsys.readouterr().out
    assert "MAE x" in printed and "C3" in printed
    result = json.loads((out / "evaluate_C3.json").read_text())
    for key in ("mae_x_m", "mae_u_m_s", "mae_Fx_N", "mae_Fy_N", "x_error_pct_travel", "rollout_ms"):
        assert result[key] >= 0
    assert result["setup"] == "C3" and result["trained_on"]["C1"]["role"] == "train"


def test_experiments_write_table_csv_and_plots(sweep_dir, tmp_path, capsys):
    out = tmp_path / "exp"
    assert _run("experiments", "--data", str(sweep_dir), "--out", str(out), "--epochs", "2", "--sets", "1,2",
                "--models", "f,f-coulomb,nn") == 0
    with open(out / "experiments.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [(r["set"], r["model"]) for r in rows] == [(s, m) for s in "12" for m in ("f", "f-coulomb", "nn")]
    assert all(r["diverged"] == "True" or (float(r["mae_x_m"]) >= 0 and float(r["x_error_pct_travel"]) >= 0)
               for r in rows), "two epochs of training may diverge, but then the row says so"
    table = (out / "table.txt").read_text()
    assert "0.34" in table and "9.86" in table and "12" in table, "the paper's numbers stand beside ours"
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
    assert issubclass(InputError, ValueError)


def test_deapull_entry_point_maps_bad_input_to_exit_2(sweep_dir, tmp_path, capsys):
    from workflows.cli import main
    code = main(["train", "--data", str(sweep_dir), "--train", "C1", "--val", "C9", "--model", "nn",
                 "--out", str(tmp_path / "m")])
    assert code == 2
    assert "C9.nc" in capsys.readouterr().err
