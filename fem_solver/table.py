"""Penalty contact and regularised Coulomb friction of the DEA's underside on the table.

The table is the fixed plane y = h (scene part ``[table]``; DESIGN.md: the DEA lies on the
fixed surface where it drapes). For a point of the DEA's underside at current position
x = X_ref + u::

    gap          g   = x_y − h
    penetration  δ   = ⟨−g⟩
    traction     p_n = k δ                       k = table.penalty_N_m3 (N/m³)
    slip rate    s_T = ((Δu_x, 0, Δu_z)) / Δt
    friction     t_T = −μ_g p_n s_T / √(|s_T|² + ε_v²)

The normal part is an energy (k/2 δ²), friction enters the residual directly, as in
:mod:`deapull.fem_solver.contact`. The table's reaction on the DEA, R = ∫ (p_n e_y + t_T) ds,
is recorded apart: it never enters the coin's Fx, Fy.
"""
from __future__ import annotations

from dataclasses import dataclass

import ufl


@dataclass
class TableTerms:
    energy: object             # normal penalty energy (UFL form)
    friction_residual: object  # friction virtual work (UFL form, residual sign)
    Rx: object                 # force of the table on the DEA along x (UFL form)
    Ry: object                 # force of the table on the DEA along y, upward positive (UFL form)


def table_terms(u, u_old, v, dt, ds_table, *, height_m, mu, penalty_N_m3, slip_rate_reg_m_s) -> TableTerms:
    """UFL terms of the DEA–table contact (module docstring).

    Parameters
    ----------
    u, u_old, v : displacement, its value at the last accepted step, test function
    dt : Constant, the step (s)
    ds_table : measure restricted to the DEA's underside
    height_m : y of the table's top face (m)
    mu : friction coefficient DEA–table (Constant or float)
    penalty_N_m3 : normal penalty k (N/m³)
    slip_rate_reg_m_s : friction regularisation ε_v (m/s)
    """
    x = ufl.SpatialCoordinate(ds_table.ufl_domain()) + u
    depth = ufl.max_value(height_m - x[1], 0.0)
    pn = penalty_N_m3 * depth
    s = (u - u_old) / dt
    s_T = ufl.as_vector((s[0], 0.0, s[2]))
    t_T = -mu * pn * s_T / ufl.sqrt(ufl.dot(s_T, s_T) + slip_rate_reg_m_s ** 2)
    return TableTerms(
        energy=0.5 * penalty_N_m3 * depth ** 2 * ds_table,
        friction_residual=-ufl.dot(t_T, v) * ds_table,
        Rx=t_T[0] * ds_table,
        Ry=pn * ds_table,
    )
