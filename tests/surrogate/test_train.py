"""Training (Algorithm 1): the loss falls, runs are reproducible, and f holds the coin still
in the static stage."""
from __future__ import annotations

import importlib
import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from deapull.errors import InputError
from deapull.surrogate.evaluate import evaluate
from deapull.surrogate.models import KINDS
from deapull.surrogate.rollout import rollout
from deapull.surrogate.train import TrainConfig, train
from tests.conftest import QUICK


@pytest.mark.parametrize("kind", list(KINDS))
def test_training_lowers_the_loss(trained, kind):
    result = trained(kind)
    first, last = result.history[0], result.history[result.best_epoch - 1]
    assert last["train_loss"] < 0.5 * first["train_loss"]
    assert last["val_loss"] < 0.5 * first["val_loss"]
    assert result.best_val_loss == min(h["val_loss"] for h in result.history)


def test_training_is_reproducible(sweep):
    config = TrainConfig(kind="f-coulomb", epochs=3, seed=7)
    one = train(config, [sweep["C1"]], sweep["C2"]).model.state_dict()
    two = train(config, [sweep["C1"]], sweep["C2"]).model.state_dict()
    assert one.keys() == two.keys()
    assert all(torch.allclose(one[k], two[k], rtol=0, atol=0, equal_nan=True) for k in one)


def test_early_stopping_keeps_the_best_epoch(sweep):
    result = train(TrainConfig(kind="nn", epochs=200, patience=2, lr=0.05), [sweep["C1"]], sweep["C2"])
    assert len(result.history) == result.best_epoch + 2 < 200


@pytest.mark.parametrize("setup", ["C1", "C3"])
def test_f_keeps_the_coin_still_in_the_static_stage(sweep, trained, setup):
    """Coulomb f sticks exactly while m's force is inside the friction cone. (The paper's
    law holds the coin only while |Fx| stays under its ramp μ_b (V/V^T) N, which the FEM's
    forces do not; see docs/surrogate.md and test_models for the law itself.)"""
    data = sweep[setup]
    ev = evaluate(trained("f-coulomb").model, data, engine="torch")
    static = data.V < 0.6 * data.threshold_voltage()
    assert static.sum() > 100
    assert abs(ev.x_model[static]).max() < 1e-7


@pytest.mark.parametrize("bad, match", [
    (dict(kind="gp"), "not a model"),
    (dict(kind="nn", epochs=0), "epochs"),
    (dict(kind="nn", lr=-1.0), "learning rate"),
    (dict(kind="nn", device="tpu"), "--device"),
])
def test_bad_configuration_is_refused(bad, match):
    with pytest.raises(InputError, match=match):
        TrainConfig(**bad)


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the message without a GPU")
def test_cuda_without_gpu_is_refused():
    with pytest.raises(InputError, match="no CUDA device"):
        TrainConfig(kind="nn", device="cuda")


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
@pytest.mark.parametrize("kind", list(KINDS))
def test_cuda_training_and_batched_rollout_match_the_cpu(sweep, kind):
    """On a GPU: training runs on CUDA and lowers the loss, and a batched torch rollout on
    CUDA gives the CPU's rollout (same weights) to round-off."""
    result = train(TrainConfig(kind=kind, device="cuda", **QUICK[kind]), [sweep["C1"]], sweep["C2"])
    assert result.history[-1]["train_loss"] < result.history[0]["train_loss"]
    model, data = result.model, sweep["C1"]
    phi = model.phi_of(data)
    s0, actions = data.states()[0], data.actions()
    with torch.inference_mode():
        cpu = rollout(model, phi, s0, actions, engine="torch").states[0]
        model.to("cuda")
        batch = 64
        gpu = rollout(model, phi, np.tile(s0, (batch, 1)), np.tile(actions, (batch, 1, 1)), engine="torch").states
    assert gpu.device.type == "cuda" and gpu.shape[0] == batch
    gpu = gpu.cpu()
    assert torch.allclose(gpu[0], gpu[-1], rtol=0, atol=0, equal_nan=True)
    # compare while the CPU rollout stays bounded: a briefly trained paper-law f may run away
    bounded = torch.isfinite(cpu[:, 0]) & (cpu[:, 0].abs() < 10 * data.travel_m)
    n = int(torch.cumprod(bounded.int(), 0).sum())
    assert n > 50
    scale = float(cpu[:n, 0].abs().max()) + 1e-6
    assert float((gpu[0, :n, 0] - cpu[:n, 0]).abs().max()) < 1e-3 * scale


def _val_error(model, data) -> float:
    """x error (% of travel) of the model's rollout of ``data``, computed here from x alone."""
    x = evaluate(model, data).x_model
    return float(100 * np.abs(x[1:] - data.x[1:]).mean() / np.abs(data.x).max())


def test_restarts_keep_the_seed_with_the_lowest_validation_rollout_error(sweep):
    """Three seeds; each restart's recorded score is its validation rollout error (checked
    against a single run of that seed, scored here), and the model kept is, bit for bit, the
    single run of the seed with the lowest score (here the middle one, so neither "the first"
    nor "the last" passes)."""
    config = TrainConfig(kind="f-coulomb", epochs=3, seed=11, restarts=3)
    result = train(config, [sweep["C1"]], sweep["C2"])
    assert [r["seed"] for r in result.restarts] == [11, 12, 13]
    singles = {s: train(replace(config, seed=s, restarts=1), [sweep["C1"]], sweep["C2"]) for s in (11, 12, 13)}
    scores = {s: _val_error(single.model, sweep["C2"]) for s, single in singles.items()}
    for r in result.restarts:
        assert r["val_x_error_pct"] == pytest.approx(scores[r["seed"]], rel=1e-9)
        assert r["best_val_loss"] == singles[r["seed"]].best_val_loss
    best = min(scores, key=scores.get)
    assert best == 12, f"the test needs the best seed in the middle (scores {scores})"
    assert result.seed == best and [r["kept"] for r in result.restarts] == [False, True, False]
    assert result.val_x_error_pct == pytest.approx(scores[best], rel=1e-9)
    kept, single = result.model.state_dict(), singles[best].model.state_dict()
    assert all(torch.equal(kept[k], single[k]) for k in kept)
    assert result.history == singles[best].history
    summary = result.summary()
    assert summary["selected_seed"] == best and len(summary["restarts"]) == 3 and summary["config"]["restarts"] == 3


def test_restarts_whose_rollouts_all_diverge_fall_back_to_the_validation_loss(sweep, monkeypatch):
    train_mod = importlib.import_module("deapull.surrogate.train")   # the package exports the function `train`
    monkeypatch.setattr(train_mod, "validation_rollout_error", lambda model, val_sets, phis: (math.inf, True))
    result = train(TrainConfig(kind="f-coulomb", epochs=2, seed=0, restarts=3), [sweep["C1"]], sweep["C2"])
    losses = [r["best_val_loss"] for r in result.restarts]
    assert len(set(losses)) == 3 and all(r["val_diverged"] for r in result.restarts)
    assert result.seed == result.restarts[int(np.argmin(losses))]["seed"]
    assert result.best_val_loss == min(losses)


@pytest.mark.parametrize("restarts", [0, -2, 1.5, True])
def test_restarts_below_one_are_refused_naming_the_flag(restarts):
    with pytest.raises(InputError, match=rf"--restarts {restarts!r}: must be a whole number of at least 1"):
        TrainConfig(kind="nn", restarts=restarts)
