"""Rollouts: saved and reloaded models roll out identically, both engines agree, and the
training range is guarded."""
from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch

from surrogate import native, store
from surrogate.evaluate import evaluate
from surrogate.models import KINDS
from surrogate.rollout import OutOfRangeError, OutOfRangeWarning, rollout

ENGINES = ["torch", "native"] if native.library() is not None else ["torch"]


@pytest.mark.parametrize("kind", KINDS)
def test_saved_and_reloaded_model_rolls_out_identically(sweep, trained, tmp_path, kind):
    result = trained(kind)
    store.save(result.model, tmp_path / kind, result.summary(), result.history)
    again, meta = store.load(tmp_path / kind)
    assert meta["kind"] == kind and meta["training"]["best_epoch"] == result.best_epoch
    assert (tmp_path / kind / "history.csv").read_text().count("\n") == len(result.history) + 1
    for engine in ENGINES:
        a = evaluate(result.model, sweep["C3"], engine=engine)
        b = evaluate(again, sweep["C3"], engine=engine)
        assert np.array_equal(a.x_model, b.x_model), engine
        assert a.metrics["mae_Fx_N"] == b.metrics["mae_Fx_N"]


@pytest.mark.skipif(len(ENGINES) < 2, reason="no C compiler: the native engine is not available")
@pytest.mark.parametrize("kind", KINDS)
def test_native_engine_matches_torch(sweep, trained, kind):
    data = sweep["C3"]
    model = trained(kind).model
    t = evaluate(model, data, engine="torch")
    n = evaluate(model, data, engine="native")
    assert n.metrics["engine"] == "native"
    scale = max(data.travel_m, float(np.abs(t.x_model).max()))   # a briefly trained model may run away
    assert np.abs(t.x_model - n.x_model).max() < 1e-3 * scale
    assert n.metrics["mae_x_m"] == pytest.approx(t.metrics["mae_x_m"], rel=1e-2, abs=1e-3 * data.travel_m)


def test_batched_rollout_matches_single(sweep, trained):
    model = trained("f-coulomb").model
    data = sweep["C1"]
    s0, actions = data.states()[0], data.actions()
    with torch.no_grad():
        one = rollout(model, s0, actions, engine="torch").states
        many = rollout(model, np.tile(s0, (3, 1)), np.tile(actions, (3, 1, 1)), engine="torch").states
    assert many.shape == (3, data.n_steps, 2)
    assert torch.equal(many[0], many[2])
    scale = max(data.travel_m, float(one[..., 0].abs().max()))
    assert (many - one)[..., 0].abs().max() < 1e-6 * scale
    # velocities: the tip's speed is a difference of float32 strokes over Δt, and batched and
    # single matrix products may round the stroke differently: allow a few float32 ulps of
    # the stroke per step (a batching bug would show errors of the size of u itself)
    ulp = float(np.spacing(np.float32(scale)))
    assert (many - one)[..., 1].abs().max() < 8 * ulp / float(data.dt[1:].min())


def test_rollout_is_differentiable_in_phi(sweep, trained):
    model = trained("f-coulomb").model
    data = sweep["C1"]
    model.mass_kg.requires_grad_(True)
    try:
        out = rollout(model, data.states()[0], data.actions()[:500])
        assert out.engine == "torch"
        out.states[0, -1, 0].backward()
        assert model.mass_kg.grad is not None and model.mass_kg.grad.item() != 0
    finally:
        model.mass_kg.requires_grad_(False)
        model.mass_kg.grad = None


def test_inputs_outside_the_training_range_warn_or_raise(sweep, trained):
    model = trained("nn").model
    data = sweep["C1"]
    actions = data.actions().copy()
    actions[10:, 0] *= 3.0
    with pytest.warns(OutOfRangeWarning, match=r"too hot: V = [\d.]+ V at step \d+ is outside"):
        rollout(model, data.states()[0], actions, label="too hot")
    with pytest.raises(OutOfRangeError, match="too hot: V"):
        rollout(model, data.states()[0], actions, strict=True, label="too hot")
    with warnings.catch_warnings(record=True) as caught:     # the training actions are in range
        warnings.simplefilter("always", OutOfRangeWarning)
        rollout(model, data.states()[0], data.actions()[:200])
    # (the model's own states may still drift outside what it saw: that warns about x or u)
    assert not [w for w in caught if " V = " in str(w.message) or " dt = " in str(w.message)]
