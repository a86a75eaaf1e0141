"""The dolfinx-version layer's own arithmetic (fem_solver/compat.py) against closed forms."""
from __future__ import annotations

import dolfinx
import dolfinx.fem.petsc
import numpy as np
import pytest
import ufl
from mpi4py import MPI

from deapull.fem_solver import compat


def test_a_batch_of_scalar_integrals_gives_each_integral():
    """One assembly of Σ_i f_i v_i (DG0 vector test function) summed per component, on the unit
    cube of hexahedra: ∫1 dx = 1, ∫x dx = 1/2, ∫x² ds over the boundary = 1 + 4/3 (the face x = 1
    and the four faces along x), and a term on a tagged facet group (the face y = 0: ∫(1 + z) ds =
    3/2). Broken once with the per-component sums taken as reshape(k, -1): every value came out
    wrong."""
    mesh = dolfinx.mesh.create_unit_cube(MPI.COMM_WORLD, 3, 3, 3, dolfinx.mesh.CellType.hexahedron)
    fdim = mesh.topology.dim - 1
    bottom = dolfinx.mesh.locate_entities_boundary(mesh, fdim, lambda p: np.isclose(p[1], 0.0))
    tags = dolfinx.mesh.meshtags(mesh, fdim, np.sort(bottom), np.full(len(bottom), 7, dtype=np.int32))
    x = ufl.SpatialCoordinate(mesh)
    ds7 = ufl.Measure("ds", domain=mesh, subdomain_data=tags, metadata={"quadrature_degree": 4})(7)
    forms = [1.0 * ufl.dx(domain=mesh), x[0] * ufl.dx, x[0] ** 2 * ufl.ds, (1 + x[2]) * ds7]
    got = compat.ScalarBatch(forms, mesh).values(mesh.comm)
    np.testing.assert_allclose(got, [1.0, 0.5, 1.0 + 4.0 / 3.0, 1.5], rtol=1e-12)
    one_by_one = [compat.assemble_scalar(compat.form(f), mesh.comm) for f in forms]
    assert got == pytest.approx(one_by_one, rel=1e-12)


def test_the_forms_compile_with_the_chosen_flags_and_agree_with_dolfinxs_own(monkeypatch):
    """compat.form hands FORM_CFLAGS (or $DEAPULL_FORM_CFLAGS) to the JIT, and the fast-math kernels give
    the residual of a nonlinear (neo-Hookean, mixed) energy at a random state as dolfinx's -O2 kernels do,
    to 1e-12 of its norm. Broken once with '-fsingle-precision-constant' added to the flags: the residuals
    differ by ≈ 1e-7 of the norm and it fails."""
    seen = []
    real = dolfinx.fem.form
    monkeypatch.setattr(dolfinx.fem, "form", lambda e, **kw: seen.append(kw["jit_params"]) or real(e, **kw))
    mesh = dolfinx.mesh.create_unit_cube(MPI.COMM_WORLD, 2, 2, 2, dolfinx.mesh.CellType.hexahedron)
    W = compat.function_space(mesh, compat.mixed_element(compat.element("Lagrange", mesh, 2, shape=(3,)),
                                                         compat.element("Lagrange", mesh, 1)))
    w = dolfinx.fem.Function(W)
    w.x.array[:] = 0.01 * np.random.default_rng(0).standard_normal(w.x.array.size)
    u, p = ufl.split(w)
    F = ufl.Identity(3) + ufl.grad(u)
    J = ufl.det(F)
    energy = (0.5 * (ufl.tr(F.T * F) * J ** (-2.0 / 3.0) - 3) + p * (J - 1) - p ** 2 / 8) * ufl.dx
    residual = ufl.derivative(energy, w, ufl.TestFunction(W))

    def assemble(flags):
        if flags is None:
            monkeypatch.delenv(compat.FORM_CFLAGS_ENV, raising=False)
        else:
            monkeypatch.setenv(compat.FORM_CFLAGS_ENV, flags)
        b = dolfinx.fem.petsc.assemble_vector(compat.form(residual))
        return b.array.copy()

    fast, plain = assemble(None), assemble("-O2 -g0")
    assert [s["cffi_extra_compile_args"] for s in seen] == [compat.FORM_CFLAGS.split(), ["-O2", "-g0"]]
    assert np.linalg.norm(fast - plain) <= 1e-12 * np.linalg.norm(plain)
