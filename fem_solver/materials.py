"""Hyperelastic strain energies (per unit reference volume), written once and
differentiated by UFL.

Mixed (u–p) form, exact incompressibility allowed::

    Ψ(F, p) = W_iso(F) + p (J − 1) − p² / (2 κ),     1/κ = 0 when ν = 0.5

Stationarity in p gives J − 1 = p / κ, i.e. the volumetric energy κ/2 (J − 1)².
Pure-displacement form (compressible only)::

    Ψ(F) = W_iso(F) + λ/2 (ln J)²
"""
from __future__ import annotations

import ufl


def lame(E: float, nu: float) -> tuple[float, float, float]:
    """Shear modulus μ, Lamé λ and bulk modulus κ (``inf`` for ν = 0.5)."""
    mu = E / (2.0 * (1.0 + nu))
    if nu >= 0.5:
        return mu, float("inf"), float("inf")
    lam = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    return mu, lam, E / (3.0 * (1.0 - 2.0 * nu))


def neo_hookean(F, mu):
    """Compressible neo-Hookean deviatoric part: W = μ/2 (I₁ − 3) − μ ln J."""
    J = ufl.det(F)
    return mu / 2 * (ufl.tr(F.T * F) - 3) - mu * ufl.ln(J)


def gent(F, mu, Jm):
    """Gent: W = −μ J_m / 2 · ln(1 − (I₁ − 3) / J_m) − μ ln J; locks as I₁ − 3 → J_m."""
    J = ufl.det(F)
    return -mu * Jm / 2 * ufl.ln(1 - (ufl.tr(F.T * F) - 3) / Jm) - mu * ufl.ln(J)


def isochoric_energy(F, dea):
    """The scene's hyperelastic law (``dea.material``)."""
    mu, _, _ = lame(dea.youngs_modulus_Pa, dea.poisson_ratio)
    if dea.material == "gent":
        return gent(F, mu, dea.gent_locking_I1)
    return neo_hookean(F, mu)


def mixed_energy(F, p, dea):
    """Ψ(F, p) for the Taylor–Hood u–p form."""
    _, _, kappa = lame(dea.youngs_modulus_Pa, dea.poisson_ratio)
    J = ufl.det(F)
    psi = isochoric_energy(F, dea) + p * (J - 1)
    if kappa != float("inf"):
        psi -= p ** 2 / (2 * kappa)
    return psi


def displacement_energy(F, dea):
    """Ψ(F) for the pure-displacement form (ν < 0.5)."""
    _, lam, _ = lame(dea.youngs_modulus_Pa, dea.poisson_ratio)
    J = ufl.det(F)
    return isochoric_energy(F, dea) + lam / 2 * ufl.ln(J) ** 2
