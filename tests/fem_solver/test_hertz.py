"""A rounded edge on a flat follows Hertz's line-contact law.

The DEA's rounded free edge rests on the coin's flat top. Its model in plane strain: a slab of the
scene's elastomer (incompressible neo-Hookean, E = 0.56 MPa, Taylor–Hood u–p) whose cross-section is
a half-disc of radius R = 0.5 mm (``dea.free_edge_radius_m``), pressed with its top face onto the flat
top of a rigid coin by the contact terms the solver uses (:func:`deapull.fem_solver.contact.contact_terms`,
frictionless). Hertz (Johnson, Contact Mechanics, §4.3) for a cylinder on a rigid flat:

    b = √(4 P R / (π E*)),   E* = E / (1 − ν²) = 4E/3 at ν = 0.5,

with P the load per unit length and b the half-width. The solved patch's half-width comes from its
pressure's second moment (for Hertz's p = p₀ √(1 − x²/b²), ∫x²p / ∫p = b²/4), so it needs no
threshold on a penalty's soft edge. At b ≈ 0.1 R the shipped coin penalty widens the patch by ≈ 2 %
(its overlap p₀/k_n spreads the pressure past b); ×10 stiffer, the law holds within 0.5 %.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from mpi4py import MPI

from deapull import scene as scenes

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="a serial mesh from gmsh")

R, THICKNESS = 0.5e-3, 0.01e-3             # half-disc radius and the slab's thickness (one layer)
H_FINE, H_FAR, ZONE = 8e-6, 0.15e-3, 0.08e-3


def _half_disc_slab():
    """Second-order tetrahedra of the half-disc x² + (y − R)² ≤ R², y ≤ R, extruded over THICKNESS in z,
    8 µm elements within 80 µm of the bottom point (0, 0)."""
    import gmsh
    from dolfinx.io import gmshio
    from deapull.meshing.build import gmsh_session
    with gmsh_session("hertz") as model:
        occ = model.occ
        disc = occ.addDisk(0.0, R, 0.0, R, R)
        upper = occ.addRectangle(-2 * R, R, 0.0, 4 * R, 2 * R)
        half, _ = occ.cut([(2, disc)], [(2, upper)])
        occ.synchronize()
        field = model.mesh.field
        field.add("Box", 1)
        for key, value in (("VIn", H_FINE), ("VOut", H_FAR), ("XMin", -ZONE), ("XMax", ZONE), ("YMin", -1.0),
                           ("YMax", ZONE / 3), ("ZMin", -1.0), ("ZMax", 1.0), ("Thickness", ZONE)):
            field.setNumber(1, key, value)
        field.setAsBackgroundMesh(1)
        for key in ("Mesh.MeshSizeExtendFromBoundary", "Mesh.MeshSizeFromPoints", "Mesh.MeshSizeFromCurvature"):
            gmsh.option.setNumber(key, 0)
        slab = occ.extrude(half, 0.0, 0.0, THICKNESS, numElements=[1])
        occ.synchronize()
        model.addPhysicalGroup(3, [tag for dim, tag in slab if dim == 3], 1)
        model.mesh.generate(3)
        model.mesh.setOrder(2)
        mesh, _, _ = gmshio.model_to_mesh(model, MPI.COMM_SELF, 0, gdim=3)
    return mesh


def _press(mesh, penalty_N_m3: float, depths_m) -> list[tuple[float, float]]:
    """(P, b) at each imposed depth of the top face: P the load per unit length (N/m), b the half-width
    from the pressure's second moment (m). Newton with a fresh Jacobian, to a 1e-9 relative residual."""
    import dolfinx
    import dolfinx.fem.petsc as fp
    import ufl
    from petsc4py import PETSc
    from deapull.fem_solver import materials
    from deapull.fem_solver.contact import contact_terms

    dea = scenes.load("coin_pull").dea
    cell = mesh.ufl_cell()
    W = dolfinx.fem.FunctionSpace(mesh, ufl.MixedElement([ufl.VectorElement("Lagrange", cell, 2),
                                                          ufl.FiniteElement("Lagrange", cell, 1)]))
    w, dw = dolfinx.fem.Function(W), dolfinx.fem.Function(W)
    u, p = ufl.split(w)
    ds = ufl.Measure("ds", domain=mesh, metadata={"quadrature_degree": 8})
    zero, one = dolfinx.fem.Constant(mesh, 0.0), dolfinx.fem.Constant(mesh, 1.0)
    # a flat: the top face y = 0 of a coin 0.1 m in radius, far from its rim
    flat = contact_terms(u, u, ufl.TestFunctions(W)[0], zero, zero, one, ds, center_x0=0.0, top_y=0.0, radius=0.1, edge_radius=1e-3,
                         mu=0.0, penalty_N_m3=penalty_N_m3, slip_rate_reg_m_s=1e-5, edge_shape="c2")
    energy = materials.mixed_energy(ufl.Identity(3) + ufl.grad(u), p, dea) * ufl.dx(metadata={"quadrature_degree": 4})
    residual = ufl.derivative(energy + flat.energy, w, ufl.TestFunction(W))
    F, J = dolfinx.fem.form(residual), dolfinx.fem.form(ufl.derivative(residual, w))

    Vu = W.sub(0)
    spaces = [(Vu.sub(i), Vu.sub(i).collapse()[0]) for i in range(3)]
    top = dolfinx.mesh.locate_entities_boundary(mesh, 2, lambda x: np.isclose(x[1], R))
    every = dolfinx.fem.locate_dofs_geometrical(spaces[2], lambda x: np.full(x.shape[1], True))
    ux, uy, uz = (dolfinx.fem.Function(s[1]) for s in spaces)
    bcs = [dolfinx.fem.dirichletbc(uz, every, Vu.sub(2)),                                   # plane strain
           dolfinx.fem.dirichletbc(ux, dolfinx.fem.locate_dofs_topological(spaces[0], 2, top), Vu.sub(0)),
           dolfinx.fem.dirichletbc(uy, dolfinx.fem.locate_dofs_topological(spaces[1], 2, top), Vu.sub(1))]
    A, b = fp.create_matrix(J), fp.create_vector(F)
    ksp = PETSc.KSP().create(MPI.COMM_SELF)
    ksp.setType("preonly")
    ksp.getPC().setType("lu")
    ksp.getPC().setFactorSolverType("mumps")

    x = ufl.SpatialCoordinate(mesh)
    load = dolfinx.fem.form(flat.pressure * ds)
    moment = dolfinx.fem.form(flat.pressure * (x[0] + u[0]) ** 2 * ds)
    out = []
    for depth in depths_m:
        uy.x.array[:] = -depth
        for it in range(30):
            with b.localForm() as local:
                local.set(0.0)
            fp.assemble_vector(b, F)
            fp.apply_lifting(b, [J], [bcs], x0=[w.vector], scale=-1.0)
            b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            fp.set_bc(b, bcs, w.vector, -1.0)
            norm = b.norm()
            first = norm if it == 0 else first
            if it > 0 and norm <= 1e-9 * first:
                break
            A.zeroEntries()
            fp.assemble_matrix(A, J, bcs)
            A.assemble()
            ksp.setOperators(A)
            b.scale(-1.0)
            ksp.solve(b, dw.vector)
            w.x.array[:] += dw.x.array
        else:
            pytest.fail(f"Newton did not converge at depth {depth:g} m (residual {norm:.3g} from {first:.3g})")
        total = dolfinx.fem.assemble_scalar(load)
        out.append((total / THICKNESS, 2.0 * math.sqrt(dolfinx.fem.assemble_scalar(moment) / total)))
    return out


def _hertz_half_width(P: float) -> float:
    dea = scenes.load("coin_pull").dea
    e_star = dea.youngs_modulus_Pa / (1.0 - 0.5 ** 2)
    return math.sqrt(4.0 * P * R / (math.pi * e_star))


@pytest.mark.parametrize("penalty_factor, tolerance", [(1.0, 0.05), (10.0, 0.005)])
def test_a_rounded_edge_on_a_flat_follows_hertz_line_contact(penalty_factor, tolerance):
    """The half-width against the load at b ≈ 0.1 R: within 5 % at the shipped coin penalty, within
    0.5 % at ten times it (the penalty's overlap is what separates the two)."""
    assert scenes.load("coin_pull").dea.free_edge_radius_m == R
    k_n = scenes.load("coin_pull").contact.penalty_N_m3 * penalty_factor
    (P, b), = _press(_half_disc_slab(), k_n, (2e-6, 4e-6, 6e-6))[-1:]
    assert 0.08 < b / R < 0.12                          # small enough for Hertz, resolved by ~6 elements
    assert b == pytest.approx(_hertz_half_width(P), rel=tolerance)
