"""Electromechanics of the ideal dielectric: the Maxwell stress as an energy.

The active stack is n films of thickness t with compliant electrodes and the voltage V
across each, so the nominal (referential) field through the thickness is E₀ = V / t
along y. The electrostatic part of the free energy per unit reference volume is::

    W_el(F, E₀) = − (ε/2) · J · C⁻¹ : (E₀ ⊗ E₀),     C = Fᵀ F,  ε = ε₀ ε_r

Its derivative with respect to F is the (nominal) Maxwell stress; UFL takes it. With
``solver.electrostatics = "coupled"`` the homogenised stack potential φ is an unknown
(φ = 0 on the bottom electrode, n·V on the top, E₀ = −∇φ) and stationarity in φ is
Gauss's law Div D = 0 with D = ε J C⁻¹ E₀.
"""
from __future__ import annotations

import ufl

EPSILON_0 = 8.8541878128e-12  # F/m


def permittivity(dea) -> float:
    return EPSILON_0 * dea.relative_permittivity


def electrostatic_energy(F, E0, eps):
    """−(ε/2) J C⁻¹:(E₀⊗E₀) — the ideal-dielectric energy whose F-derivative is the Maxwell stress."""
    J = ufl.det(F)
    C_inv = ufl.inv(F.T * F)
    return -eps / 2 * J * ufl.inner(C_inv, ufl.outer(E0, E0))


def nominal_field(voltage, dea):
    """Prescribed E₀ = (0, V/t, 0) through the film thickness (``voltage`` may be a Constant)."""
    return ufl.as_vector((0.0, voltage / dea.film_thickness_m, 0.0))


def stack_voltage(voltage, dea):
    """Potential of the top electrode in the homogenised stack: n_films · V."""
    return voltage * dea.active_thickness_m / dea.film_thickness_m


def free_strain(voltage: float, dea) -> float:
    """Small-strain in-plane actuation strain ε* = ε E₀² / (2E) of a free film
    (docs/physics.md, "Sizing")."""
    e0 = voltage / dea.film_thickness_m
    return permittivity(dea) * e0 ** 2 / (2 * dea.youngs_modulus_Pa)
