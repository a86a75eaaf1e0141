"""φ as a value: built from a dataset, moved and indexed like a tensor, and passed to every
step — so a batch may mix coins and a model keeps no coin of its own."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from deapull.surrogate.phi import Phi
from deapull.surrogate.rollout import rollout


def test_phi_of_a_dataset_reads_its_coin(sweep):
    data = sweep["C3"]
    phi = Phi.of(data, v_threshold_V=130.0)
    assert phi.as_dict() == {"mass_kg": data.mass_kg, "mu_b": 0.2, "mu_t": 0.55, "v_threshold_V": 130.0}
    assert math.isnan(Phi.of(data).v_threshold_V)
    with pytest.raises(AttributeError):
        phi.mu_b = 0.3          # frozen: a coin is a value


def test_phi_moves_indexes_and_stacks_like_its_tensors():
    rows = Phi.rows([Phi(1.0, 0.2, 0.5), Phi(2.0, 0.25)], [2, 3], dtype=torch.float64)
    assert len(rows) == 5 and rows.mass_kg.tolist() == [1, 1, 2, 2, 2] and rows.mass_kg.dtype == torch.float64
    assert rows.mu_t[:2].tolist() == [0.5, 0.5] and torch.isnan(rows.mu_t[2:]).all()
    picked = rows[torch.tensor([4, 0])]
    assert picked.mu_b.tolist() == [0.25, 0.2] and len(picked) == 2
    one = Phi(1e-3, 0.2, 0.5).to(dtype=torch.float32)
    assert one.mass_kg.dtype == torch.float32 and one.mass_kg.dim() == 0 and len(one) == 1
    assert one[torch.tensor([0, 0, 0])].mu_t.item() == pytest.approx(0.5), "a scalar field is shared by all rows"
    with pytest.raises(ValueError, match="φ.mass_kg holds 5 values"):
        rows.value("mass_kg")


def test_a_batch_of_coins_rolls_out_like_each_coin_alone(sweep, trained):
    """Per-row φ: one batched rollout of C1's and C5's coins (μ_b 0.2 and 0.25) equals the
    two rollouts one at a time, and the coins differ."""
    model = trained("f-coulomb").model
    data = sweep["C1"]
    coins = [model.phi_of(sweep["C1"]), model.phi_of(sweep["C5"])]
    s0, actions = data.states()[0], data.actions()
    with torch.no_grad():
        alone = [rollout(model, phi, s0, actions, engine="torch").states[0] for phi in coins]
        batch = Phi.rows(coins, [1, 1], dtype=torch.float32)
        both = rollout(model, batch, np.tile(s0, (2, 1)), np.tile(actions, (2, 1, 1)), engine="torch").states
    scale = data.travel_m
    for i in range(2):
        assert (both[i, :, 0] - alone[i][:, 0]).abs().max() < 1e-6 * scale
    assert (alone[0][:, 0] - alone[1][:, 0]).abs().max() > 0.1 * scale, "a rougher coin moves less"


@pytest.mark.parametrize("kind", ["f", "f-coulomb"])
def test_the_model_keeps_no_coin(sweep, trained, kind):
    """Rolling out another coin in between changes nothing: no state picks the coin."""
    model = trained(kind).model
    assert not {"mass_kg", "mu_b", "mu_t", "v_threshold_V"} & set(model.state_dict())
    a = model.phi_of(sweep["C3"])
    b = replace(a, mu_b=a.mu_b / 2)         # a slipperier coin, which surely moves
    data = sweep["C3"]
    s0, actions = data.states()[0], data.actions()
    with torch.no_grad():
        first = rollout(model, a, s0, actions, engine="torch").states
        other = rollout(model, b, s0, actions, engine="torch").states
        again = rollout(model, a, s0, actions, engine="torch").states
    assert torch.allclose(first, again, rtol=0, atol=0, equal_nan=True)
    assert not torch.allclose(first, other, equal_nan=True), "the coins differ"


def test_rollout_gradient_per_coin_of_a_batch(sweep, trained):
    """Gradients w.r.t. per-row φ: the final x of rollout i depends on the mass of coin i only."""
    model = trained("f-coulomb").model
    data = sweep["C1"]
    mass = torch.full((2,), data.mass_kg, requires_grad=True)
    phi = Phi(mass, torch.tensor([0.2, 0.25]), data.mu_t)
    n = 500
    out = rollout(model, phi, np.tile(data.states()[0], (2, 1)), np.tile(data.actions()[:n], (2, 1, 1)))
    (grad,) = torch.autograd.grad(out.states[0, -1, 0], mass)
    assert grad[0].item() != 0 and grad[1].item() == 0
