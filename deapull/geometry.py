"""Geometry of the scene's rigid bodies, in NumPy (no FEniCSx): the coin's (or stop's) rounded rim.

The contact's UFL expression (:mod:`deapull.fem_solver.contact`) and these twins describe the same
obstacle; the solver's penetration checks, the report's pictures and the tests use these.
"""
from __future__ import annotations

import numpy as np


def _rim_offsets(rho, y, top_y: float, radius: float, edge_radius: float):
    """(q_ρ, q_y) from the fillet's centre line, and whether the point lies beyond both (the rim)."""
    q_r, q_y = rho - (radius - edge_radius), y - (top_y - edge_radius)
    return q_r, q_y, (q_r > 0) & (q_y > 0)


def _rim(q_r, q_y, edge_radius: float, edge_shape: str):
    """On the rim (q_ρ, q_y > 0): the distance and the normal's (n_ρ, n_y) of the edge's profile."""
    a, b = np.maximum(q_r, 0.0), np.maximum(q_y, 0.0)
    if edge_shape == "c2":
        norm = np.cbrt(a ** 3 + b ** 3)
        grad = np.sqrt(a ** 4 + b ** 4)
        safe = np.where(grad > 0, grad, 1.0)
        return (norm - edge_radius) * norm ** 2 / safe, a ** 2 / safe, b ** 2 / safe
    q = np.hypot(a, b)
    safe = np.where(q > 0, q, 1.0)
    return q - edge_radius, a / safe, b / safe


def rounded_cylinder_distance(rho, y, top_y: float, radius: float, edge_radius: float, edge_shape: str = "circular"):
    """Signed distance (m, negative inside) of points at distance ``rho`` from the axis and
    height ``y`` to the upright cylinder with a rounded top rim — NumPy twin of the UFL
    expression in ``fem_solver.contact.contact_terms`` (inside the body only the
    nearer of the top face and the side wall counts, as there)."""
    q_r, q_y, corner = _rim_offsets(rho, y, top_y, radius, edge_radius)
    flat = np.where(q_y > q_r, q_y, q_r) - edge_radius
    return np.where(corner, _rim(q_r, q_y, edge_radius, edge_shape)[0], flat)


def rounded_cylinder_normal(rho, y, top_y: float, radius: float, edge_radius: float, edge_shape: str = "circular"):
    """Outward normal (n_ρ, n_y) of that cylinder at the same points, and whether each lies on the
    rim — NumPy twin of ``n`` in
    ``fem_solver.contact.contact_terms`` (e_y on the top face, e_ρ on the side wall)."""
    q_r, q_y, corner = _rim_offsets(rho, y, top_y, radius, edge_radius)
    _, rim_r, rim_y = _rim(q_r, q_y, edge_radius, edge_shape)
    top = q_y > q_r
    n_r = np.where(corner, rim_r, np.where(top, 0.0, 1.0))
    n_y = np.where(corner, rim_y, np.where(top, 1.0, 0.0))
    return n_r, n_y, corner
