"""The held-out-protocol experiment (deapull experiments-protocols): which runs it tests,
what it writes, that it resumes without training again, and the CLI's table.

Excitation runs are stand-ins here (copies of the committed test sweep's ramps under the
names ``<coin>_<protocol>.nc``): the plumbing is under test, not the physics."""
from __future__ import annotations

import json
import shutil

import pytest

from deapull.errors import InputError
from deapull.surrogate import protocol_experiments as pe
from deapull.surrogate.train import TrainConfig

DESIGN = pe.Design(train_coins=("C1",), val_coins=("C2",), test_coins=("C3",), train_protocols=("ramp", "rhr"),
                   test_protocols=("triangle",))


@pytest.fixture()
def folders(sweep_dir, tmp_path):
    excitation = tmp_path / "excitation"
    excitation.mkdir()
    for coin in ("C1", "C2", "C3"):
        for protocol, source in (("rhr", "C4"), ("triangle", "C5")):
            shutil.copy(sweep_dir / f"{source}.nc", excitation / f"{coin}_{protocol}.nc")
    return sweep_dir, excitation


def test_the_cases_are_the_held_out_runs(folders):
    data, excitation = folders
    got = pe.cases(DESIGN, data, excitation)
    assert [(c, p) for c, p, _ in got if p == "ramp"] == [(f"C{i}", "ramp") for i in range(3, 9)]
    assert ("C3", "rhr", "held-out coin") in got                                 # training protocol, new coin
    assert ("C3", "triangle", "held-out coin and protocol") in got
    assert {(c, r) for c, p, r in got if p == "triangle"} == {("C1", "held-out protocol"),
                                                              ("C2", "held-out protocol"),
                                                              ("C3", "held-out coin and protocol")}
    assert not any(c in ("C1", "C2") and p in ("ramp", "rhr") for c, p, _ in got)   # nothing trained on
    with pytest.raises(InputError, match="two roles"):
        pe.Design(train_coins=("C1",), val_coins=("C1",)).check()
    with pytest.raises(InputError, match="both trained on and held out"):
        pe.Design(train_protocols=("ramp", "triangle"), test_protocols=("triangle",)).check()


def test_writes_the_tables_and_resumes_without_training_again(folders, tmp_path):
    import torch
    torch.set_num_threads(1)          # as the command does: small networks, a shared machine
    data, excitation = folders
    out = tmp_path / "out"
    base = TrainConfig(kind="f", epochs=2, patience=2, batch_size=512)
    kinds = ("f-memory", "nn")
    rows = pe.run(data, out, base, excitation_dir=excitation, kinds=kinds, design=DESIGN)
    assert len(rows) == 2 * 10                                     # 6 ramps + C3_rhr + 3 triangles, per model
    for name in ("protocols.csv", "protocols.md", "protocols.json", "protocols.png"):
        assert (out / name).is_file(), name
    md = (out / "protocols.md").read_text()
    assert "| f (tip memory) |" in md and "triangle" in md and "held-out coin and protocol" in md
    summary = pe.summarise(rows, kinds)
    assert summary[0]["ramp_n"] == 6 and summary[0]["triangle_n"] == 3 and summary[0]["rhr_n"] == 1
    stamps = {k: (out / k / "model.pt").stat().st_mtime_ns for k in kinds}
    evals = {p: p.stat().st_mtime_ns for p in (out / "nn" / "eval").glob("*.json")}
    again = pe.run(data, out, base, excitation_dir=excitation, kinds=kinds, design=DESIGN)
    assert {k: (out / k / "model.pt").stat().st_mtime_ns for k in kinds} == stamps       # not trained again
    assert {p: p.stat().st_mtime_ns for p in (out / "nn" / "eval").glob("*.json")} == evals   # not evaluated again
    key = lambda r: (r["model"], r["run"])                                                  # noqa: E731
    assert [r["x_error_pct_travel"] for r in sorted(again, key=key)] == \
        [r["x_error_pct_travel"] for r in sorted(rows, key=key)]
    text = pe.format_text(summary, kinds)
    assert "x error [% of travel]" in text and "f (tip memory): mean <= 2 %" in text


def test_the_command_prints_the_held_out_table_beside_the_ramp_table(folders, tmp_path, capsys):
    from deapull.io import write_csv
    from deapull.surrogate.experiments import COLUMNS
    from deapull.workflows.cli import main
    data, excitation = folders
    ramp = tmp_path / "ramp"
    write_csv(ramp / "experiments.csv", [{"set": 1, "train": "C1", "val": "C2", "test": "C3", "model": k,
                                          "mae_x_m": 1e-5, "x_error_pct_travel": 1.5, "diverged": False}
                                         for k in ("f-coulomb", "nn")], COLUMNS)
    code = main(["experiments-protocols", "--data", str(data), "--excitation", str(excitation), "--out",
                 str(tmp_path / "out"), "--models", "nn", "--train-coins", "C1", "--val-coins", "C2",
                 "--test-coins", "C3", "--train-protocols", "ramp,rhr", "--test-protocols", "triangle",
                 "--epochs", "2", "--ramp-results", str(ramp), "--restarts", "2"])
    printed = capsys.readouterr().out
    assert code == 0
    # two seeds, scored on the validation coin's runs (C2's ramp and rhr: the mean of their rollout errors)
    from deapull.surrogate import store
    from deapull.surrogate.data import load_setup
    from deapull.surrogate.evaluate import evaluate
    model, meta = store.load(tmp_path / "out" / "nn")
    restarts = meta["training"]["restarts"]
    assert [r["seed"] for r in restarts] == [0, 1] and sum(r["kept"] for r in restarts) == 1
    kept = next(r for r in restarts if r["kept"])
    assert meta["training"]["selected_seed"] == kept["seed"]
    val_runs = [load_setup(data / "C2.nc"), load_setup(excitation / "C2_rhr.nc")]
    errors = [evaluate(model, run).metrics["x_error_pct_travel"] for run in val_runs]
    assert kept["val_x_error_pct"] == pytest.approx(sum(errors) / 2, rel=1e-9)
    assert kept["val_x_error_pct"] == min(r["val_x_error_pct"] for r in restarts)
    assert "the paper's six sets" in printed and "1 (C1/C2/C3)" in printed
    assert "Held-out protocols and coins" in printed and "triangle" in printed


def test_held_out_pairs_never_train_or_validate_on_the_pair_they_test(sweep_dir, tmp_path):
    from deapull.surrogate.protocol_experiments import PAIRS, pair_designs, run_pairs
    from deapull.surrogate.train import TrainConfig
    designs = pair_designs()
    assert [held for held, _ in designs] == list(PAIRS)
    for held, d in designs:
        seen = set(d.train_coins) | set(d.val_coins)
        assert not seen & set(held) and len(d.train_coins) == 4 and len(seen) == 5
        # the validation coin's friction is not trained on: its sibling sits out
        (sibling,) = [c for p in PAIRS if d.val_coins[0] in p for c in p if c != d.val_coins[0]]
        assert sibling not in d.train_coins
    rows = run_pairs(sweep_dir, tmp_path, TrainConfig(kind="f-coulomb", epochs=2), kinds=("f-coulomb",))
    assert [(r["pair"], r["run"]) for r in rows] == [("/".join(p), c) for p in PAIRS for c in p]
    for r in rows:   # each model's card names its training coins: never the pair it is tested on
        meta = json.loads((tmp_path / ("pair_" + r["pair"].replace("/", "_")) / "f-coulomb" / "model.json").read_text())
        assert r["run"] not in meta["card"]["training_coins"] + meta["card"]["validation_coins"]
    assert "largest x error on a held-out ramp" in (tmp_path / "pairs.md").read_text()


def test_held_out_pairs_test_the_pairs_excitation_runs_without_training_on_excitation(sweep_dir, tmp_path):
    """With an excitation folder the pair designs still train on the other coins' ramps, and test the
    held-out pair's excitation runs beside its ramps (stand-ins here: C1_rhr, C3_rhr and C5_rhr; none for
    C7/C8), reported apart; the ramp-only models of a run without
    the folder are reused, not trained again. Broken once (the whole design compared for reuse, test
    protocols included): the models were trained again."""
    from deapull.surrogate.protocol_experiments import run_pairs
    excitation = tmp_path / "excitation"
    excitation.mkdir()
    for coin, source in (("C1", "C4"), ("C3", "C6"), ("C5", "C7")):
        shutil.copy(sweep_dir / f"{source}.nc", excitation / f"{coin}_rhr.nc")
    out, cfg = tmp_path / "out", TrainConfig(kind="f-coulomb", epochs=2)
    run_pairs(sweep_dir, out, cfg, kinds=("f-coulomb",))
    stamp = (out / "pair_C1_C2" / "f-coulomb" / "model.pt").stat().st_mtime_ns
    rows = run_pairs(sweep_dir, out, cfg, kinds=("f-coulomb",), excitation_dir=excitation)
    assert (out / "pair_C1_C2" / "f-coulomb" / "model.pt").stat().st_mtime_ns == stamp
    runs = {}
    for r in rows:
        runs.setdefault(r["pair"], set()).add(r["run"])
    assert runs == {"C1/C2": {"C1", "C2", "C1_rhr"}, "C3/C4": {"C3", "C4", "C3_rhr"}, "C5/C6": {"C5", "C6", "C5_rhr"},
                    "C7/C8": {"C7", "C8"}}
    meta = json.loads((out / "pair_C1_C2" / "f-coulomb" / "model.json").read_text())
    assert meta["training"]["design"]["train_protocols"] == ["ramp"]
    pairs = json.loads((out / "pairs.json").read_text())
    assert {r["protocol"] for r in pairs["runs"]} == {"ramp", "rhr"}
    text = (out / "pairs.md").read_text()
    assert "largest x error on a held-out ramp" in text and "largest x error on a held-out excitation run" in text
