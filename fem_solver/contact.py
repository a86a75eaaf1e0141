"""Penalty contact and regularised Coulomb friction of the DEA's underside on a rigid
upright cylinder (the coin, or a fixed stop), by its signed distance.

The obstacle is the cylinder of radius r around the vertical axis through
(x_c0 + X, ·, 0), below the plane y = y_top, X its displacement along x, its top rim
rounded with a fillet of radius r_f (a real coin's rim is rounded; a sharp corner would
give a normal that jumps from e_y to e_ρ). For a point of the DEA at current position
x = X_ref + u, with ρ its distance from the axis, q = (ρ − (r − r_f), x_y − (y_top − r_f))::

    distance     d   = |q| − r_f                on the fillet (both q > 0)
                     = max(q_ρ, q_y) − r_f      elsewhere (flat top or side wall)
    penetration  δ   = ⟨−d⟩
    normal       n   = q/|q| on the fillet, else e_y or e_ρ (outward)
    traction     p_n = k_n δ,                       k_n = contact.penalty_N_m3 (N/m³)
    slip rate    s   = (Δu − ΔX e_x) / Δt,  s_T = s − (s·n) n
    friction     t_T = −μ p_n s_T / √(|s_T|² + ε_v²)

With ``edge_shape = "c2"`` the rim is the quarter of the superellipse |q_ρ|³ + |q_y|³ = r_f³
instead of the circle: its curvature rises from 0 at both tangencies (the flat top and the side
wall) to 1.78 / r_f at 45°, so the gap, the normal and the curvature are continuous where the
DEA's edge rides from the top face onto the rim. There ``d`` is the first-order distance
(‖q‖₃ − r_f) / |∇‖q‖₃| and ``n`` = ∇‖q‖₃ / |∇‖q‖₃| = (q_ρ², q_y²) / |(q_ρ², q_y²)|.

Both the flat top face and the rim / side wall are obstacles: a DEA tip that curls
over the far rim pushes on the side wall. The normal part is an energy (k_n/2 δ²);
friction is not, so it enters the residual directly; UFL differentiates both. The
regularisation is on the slip *rate* (ε_v in m/s), so results do not depend on the
time step as Δt → 0; below ε_v friction acts as a stiff viscous stick.

The force of the DEA on the obstacle is −∫ (p_n n + t_T) ds: Fx its x component, and
Fy = ∫ (p_n n + t_T)_y ds the pressing force, positive downward.
"""
from __future__ import annotations

from dataclasses import dataclass

import ufl

from deapull.geometry import rounded_cylinder_distance, rounded_cylinder_normal  # noqa: F401  (NumPy twins)


@dataclass
class ObstacleTerms:
    energy: object             # normal penalty energy (UFL form)
    friction_residual: object  # friction virtual work (UFL form, residual sign)
    Fx: object                 # force of the DEA on the obstacle along x (UFL form)
    Fy: object                 # pressing force, positive downward (UFL form)
    pressure: object           # normal traction p_n (UFL expression, Pa), for the contact centre


def contact_terms(u, u_old, v, X, X_old, dt, ds_contact, *, center_x0, top_y, radius, edge_radius, mu,
                  penalty_N_m3, slip_rate_reg_m_s, edge_shape="circular"):
    """UFL terms of penalty contact and regularised Coulomb friction against a rigid cylinder.

    Parameters
    ----------
    u, u_old, v : displacement, its value at the last accepted step, test function
    X, X_old : Constants, obstacle displacement along x now and at the last accepted step (m)
    dt : Constant, the step (s)
    ds_contact : measure restricted to the DEA's contact surface
    center_x0, top_y, radius : obstacle geometry in the reference configuration (m)
    edge_radius : fillet radius of the top rim (m), < radius
    edge_shape : "circular" (a quarter circle) or "c2" (the superellipse of curvature-continuous blend)
    mu : friction coefficient DEA–obstacle (Constant or float)
    penalty_N_m3 : normal penalty stiffness k_n
    slip_rate_reg_m_s : friction regularisation ε_v (m/s)
    """
    n, depth = _normal_and_depth(u, X, ds_contact, center_x0, top_y, radius, edge_radius, edge_shape)
    pn = penalty_N_m3 * depth
    t_T = mu * _unit_friction(u, u_old, (X - X_old) / dt, dt, n, pn, slip_rate_reg_m_s)
    traction = pn * n + t_T        # on the DEA, from the obstacle
    return ObstacleTerms(
        energy=0.5 * penalty_N_m3 * depth ** 2 * ds_contact,
        friction_residual=-ufl.dot(t_T, v) * ds_contact,
        Fx=-traction[0] * ds_contact,
        Fy=traction[1] * ds_contact,
        pressure=pn,
    )


def _normal_and_depth(u, X, ds_contact, center_x0, top_y, radius, edge_radius, edge_shape="circular"):
    """The obstacle's outward normal n and the penetration δ at the DEA's current points."""
    x = ufl.SpatialCoordinate(ds_contact.ufl_domain()) + u
    rx, rz = x[0] - center_x0 - X, x[2]
    rho = ufl.sqrt(rx ** 2 + rz ** 2 + (1e-9 * radius) ** 2)
    e_y, e_rho = ufl.as_vector((0.0, 1.0, 0.0)), ufl.as_vector((rx / rho, 0.0, rz / rho))
    q_r, q_y = rho - (radius - edge_radius), x[1] - (top_y - edge_radius)
    # 0/1 indicators times smooth branches (FFCx cannot factor conditionals whose branches
    # differ in their dependence on the arguments)
    corner = ufl.conditional(ufl.And(ufl.gt(q_r, 0.0), ufl.gt(q_y, 0.0)), 1.0, 0.0)
    on_top = ufl.conditional(ufl.gt(q_y, q_r), 1.0, 0.0)
    tiny = 1e-9 * radius
    if edge_shape == "c2":
        a, b = ufl.max_value(q_r, 0.0), ufl.max_value(q_y, 0.0)
        norm = (a ** 3 + b ** 3 + tiny ** 3) ** (1.0 / 3.0)
        grad = ufl.sqrt(a ** 4 + b ** 4 + tiny ** 4)          # |∇‖q‖₃| ‖q‖₃²
        rim_distance = (norm - edge_radius) * norm ** 2 / grad
        rim_normal = (a ** 2 * e_rho + b ** 2 * e_y) / grad
    else:
        q = ufl.sqrt(q_r ** 2 + q_y ** 2 + tiny ** 2)
        rim_distance = q - edge_radius
        rim_normal = (q_r * e_rho + q_y * e_y) / q
    distance = corner * rim_distance + (1 - corner) * (on_top * q_y + (1 - on_top) * q_r - edge_radius)
    n = corner * rim_normal + (1 - corner) * (on_top * e_y + (1 - on_top) * e_rho)
    return n, ufl.max_value(-distance, 0.0)


def _unit_friction(u, u_old, coin_velocity, dt, n, pn, slip_rate_reg_m_s):
    """Friction traction on the DEA per unit μ for an obstacle moving at ``coin_velocity`` along x."""
    s = (u - u_old) / dt - coin_velocity * ufl.as_vector((1.0, 0.0, 0.0))
    s_T = s - ufl.dot(s, n) * n
    return -pn * s_T / ufl.sqrt(ufl.dot(s_T, s_T) + slip_rate_reg_m_s ** 2)


@dataclass
class PatchProbe:
    """Forms that read the contact patch's side of the friction off a solved step (DEA-side: what
    any coin under this patch would feel), all as forces on the obstacle along x (N, of the modelled
    mesh) or their weights:

    * ``pressure`` ∫ p_n ds and ``pressure_vx`` ∫ p_n Δu_x/Δt ds: the traction-weighted mean x velocity
      of the patch is their ratio;
    * ``normal_x`` −∫ p_n n_x ds: the normal traction's x part (the rim's fillet pushes back);
    * ``drag`` −∫ t_T,x ds per unit μ, with the obstacle's velocity the Constant ``coin_velocity``
      (set it, then assemble): the patch's friction–speed curve.
    """
    pressure: object
    pressure_vx: object
    normal_x: object
    drag: object
    coin_velocity: object


def patch_probe(u, u_old, X, dt, ds_contact, coin_velocity, *, center_x0, top_y, radius, edge_radius,
                penalty_N_m3, slip_rate_reg_m_s, edge_shape="circular") -> PatchProbe:
    """UFL forms of :class:`PatchProbe` for the obstacle of :func:`contact_terms` (same arguments;
    ``coin_velocity`` a Constant in m/s)."""
    n, depth = _normal_and_depth(u, X, ds_contact, center_x0, top_y, radius, edge_radius, edge_shape)
    pn = penalty_N_m3 * depth
    t_T = _unit_friction(u, u_old, coin_velocity, dt, n, pn, slip_rate_reg_m_s)
    return PatchProbe(pressure=pn * ds_contact, pressure_vx=pn * (u - u_old)[0] / dt * ds_contact,
                      normal_x=-pn * n[0] * ds_contact, drag=-t_T[0] * ds_contact, coin_velocity=coin_velocity)
