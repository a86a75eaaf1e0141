"""Rollouts: saved and reloaded models roll out identically, both engines agree, and the
training range is guarded."""
from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
import torch

from deapull.surrogate import native, store
from deapull.surrogate.evaluate import evaluate
from deapull.surrogate.models import KINDS
from deapull.surrogate.phi import Phi
from deapull.surrogate.rollout import OutOfRangeError, OutOfRangeWarning, rollout

ENGINES = ["torch", "native"] if native.library() is not None else ["torch"]


@pytest.mark.parametrize("kind", list(KINDS))
def test_saved_and_reloaded_model_rolls_out_identically(sweep, trained, tmp_path, kind):
    result = trained(kind)
    store.save(result.model, tmp_path / kind, result.summary(), result.history)
    again, meta = store.load(tmp_path / kind)
    assert meta["kind"] == kind and meta["training"]["best_epoch"] == result.best_epoch
    assert (tmp_path / kind / "history.csv").read_text().count("\n") == len(result.history) + 1
    for engine in (ENGINES if native.supports(result.model) else ["torch"]):
        a = evaluate(result.model, sweep["C3"], engine=engine)
        b = evaluate(again, sweep["C3"], engine=engine)
        assert np.array_equal(a.x_model, b.x_model), engine
        assert a.metrics["mae_Fx_N"] == b.metrics["mae_Fx_N"]


@pytest.mark.skipif(len(ENGINES) < 2, reason="no C compiler: the native engine is not available")
@pytest.mark.parametrize("kind", [k for k in KINDS if callable(getattr(KINDS[k], "native_kernel", None))])
def test_native_engine_matches_torch(sweep, trained, kind):
    data = sweep["C3"]
    model = trained(kind).model
    t = evaluate(model, data, engine="torch")
    n = evaluate(model, data, engine="native")
    assert n.metrics["engine"] == "native"
    scale = max(data.travel_m, float(np.abs(t.x_model).max()))   # a briefly trained model may run away
    assert np.abs(t.x_model - n.x_model).max() < 1e-3 * scale
    assert n.metrics["mae_x_m"] == pytest.approx(t.metrics["mae_x_m"], rel=1e-2, abs=1e-3 * data.travel_m)


@pytest.mark.parametrize("kind, legacy_state", [("f", {"mass_kg": 1.36e-3, "mu_b": 0.2, "v_threshold_V": 150.0}),
                                                ("f-coulomb", {"mass_kg": 1.36e-3, "mu_b": 0.2, "mu_t": 0.5})])
def test_model_folder_saved_with_phi_inside_still_loads(sweep, trained, tmp_path, kind, legacy_state):
    """Folders written while φ was part of the model (same format: φ in the state dict, the
    paper model's hyper-parameter ``law``) load and roll out like today's."""
    model = trained(kind).model
    folder = store.save(model, tmp_path / kind)
    state = torch.load(folder / store.STATE, weights_only=True)
    state.update({k: torch.tensor(v) for k, v in legacy_state.items()})
    torch.save(state, folder / store.STATE)
    meta = json.loads((folder / store.META).read_text())
    if kind == "f":
        meta["hyper_parameters"]["law"] = "paper"
    (folder / store.META).write_text(json.dumps(meta))
    again, _ = store.load(folder)
    assert np.array_equal(evaluate(again, sweep["C3"], engine="torch").x_model,
                          evaluate(model, sweep["C3"], engine="torch").x_model)


def test_batched_rollout_matches_single(sweep, trained):
    model = trained("f-coulomb").model
    data = sweep["C1"]
    s0, actions, phi = data.states()[0], data.actions(), model.phi_of(data)
    with torch.no_grad():
        one = rollout(model, phi, s0, actions, engine="torch").states
        many = rollout(model, phi, np.tile(s0, (3, 1)), np.tile(actions, (3, 1, 1)), engine="torch").states
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
    mass = torch.tensor(data.mass_kg, requires_grad=True)
    out = rollout(model, Phi(mass, data.mu_b, data.mu_t), data.states()[0], data.actions()[:500])
    assert out.engine == "torch"
    out.states[0, -1, 0].backward()
    assert mass.grad is not None and mass.grad.item() != 0


def test_inputs_outside_the_training_range_warn_or_raise(sweep, trained):
    model = trained("nn").model
    data = sweep["C1"]
    actions = data.actions().copy()
    actions[10:, 0] *= 3.0
    with pytest.warns(OutOfRangeWarning, match=r"too hot: V = [\d.]+ V at step \d+ is outside"):
        rollout(model, None, data.states()[0], actions, label="too hot")
    with pytest.raises(OutOfRangeError, match="too hot: V"):
        rollout(model, None, data.states()[0], actions, strict=True, label="too hot")
    with warnings.catch_warnings(record=True) as caught:     # the training actions are in range
        warnings.simplefilter("always", OutOfRangeWarning)
        rollout(model, None, data.states()[0], data.actions()[:200])
    # (the model's own states may still drift outside what it saw: that warns about x or u)
    assert not [w for w in caught if " V = " in str(w.message) or " dt = " in str(w.message)]
