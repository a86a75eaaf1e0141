"""Training (Algorithm 1): the loss falls, runs are reproducible, and f holds the coin still
in the static stage."""
from __future__ import annotations

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
