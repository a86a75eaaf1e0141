"""The tip-contact model's material network as the exact piecewise-affine function it is
(``TipContactModel.material_pieces``, the fast path of the MPC's native step)."""
from __future__ import annotations

import copy

import numpy as np
import torch

from deapull.surrogate.models.tip_contact import material_from_pieces

F64 = torch.float64


def test_pieces_are_the_network_to_round_off(trained):
    model = copy.deepcopy(trained("f-coulomb").model).double()
    pieces = model.material_pieces(0.0, 400.0)
    knots = pieces["knots"]
    assert len(pieces["slope"]) > 3 and np.all(np.diff(knots) > 0)
    t_knots = torch.as_tensor(knots, dtype=F64) * pieces["scale"] + pieces["mean"]
    g = torch.Generator().manual_seed(0)
    V = torch.cat([torch.linspace(0, 400, 20001, dtype=F64), 400 * torch.rand(2000, generator=g, dtype=F64),
                   t_knots.clamp(0, 400), (t_knots + 1e-9).clamp(0, 400), (t_knots - 1e-9).clamp(0, 400)])
    with torch.no_grad():
        X, Fy = model.material_response(V)
    Xp, Fyp = material_from_pieces(pieces, V)
    torch.testing.assert_close(Xp, X, rtol=0, atol=1e-12 * float(X.abs().max()))
    torch.testing.assert_close(Fyp, Fy, rtol=0, atol=1e-12 * float(Fy.abs().max()))
    # each piece's slope is the network's derivative inside it
    inside = torch.as_tensor(0.5 * (knots[:-1] + knots[1:]), dtype=F64) * pieces["scale"] + pieces["mean"]
    inside = inside[(inside > 0) & (inside < 400)].requires_grad_(True)
    X, Fy = model.material_response(inside)
    dX, = torch.autograd.grad(X.sum(), inside)
    k = np.searchsorted(knots, ((inside.detach() - pieces["mean"]) / pieces["scale"]).numpy(), side="right") - 1
    slope = torch.as_tensor(pieces["slope"][k, 0], dtype=F64) * pieces["stroke_scale"] / pieces["scale"]
    torch.testing.assert_close(slope, dX, rtol=1e-9, atol=1e-12 * float(dX.abs().max()))
