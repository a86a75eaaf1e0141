"""The DEA's nonlinear problem for one scene: spaces, energy, residual, Newton (PETSc SNES).

Only what the scene needs is assembled: no pressure for a compressible pure-displacement
scene, no electrostatic term when the voltage stays 0, no gravity at g = 0, no contact or
friction without a coin or stop, no potential unless ``solver.electrostatics = "coupled"``.
"""
from __future__ import annotations

import contextlib
import logging
import math
from dataclasses import dataclass

import dolfinx
import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from deapull.fem_solver import compat, contact, electro, materials, table
from deapull.meshing import groups
from deapull.meshing.layout import layout

log = logging.getLogger(__name__)

SNES_REASONS = {getattr(PETSc.SNES.ConvergedReason, k): k for k in dir(PETSc.SNES.ConvergedReason)
                if not k.startswith("_") and isinstance(getattr(PETSc.SNES.ConvergedReason, k), int)}


PARALLEL_FACTOR_PACKAGES = ("mumps",)
#: a Newton solve whose residual has not fallen below STALL_FACTOR x its smallest value for
#: STALL_ITERATIONS iterations has stalled and is ended as diverged (:meth:`DEAProblem._converged`):
#: at a friction reversal full Newton steps cycle through 4 residuals for all 40 iterations, each with a
#: fresh Jacobian (tests/fem_solver/test_stepping.py feeds that measured cycle to the test)
STALL_FACTOR = 0.99
STALL_ITERATIONS = 8
#: MUMPS's workspace relaxation ICNTL(14), % over its analysis estimate (its default: 20). Under
#: MPI on a loaded machine, every factorisation of a run failed from one step on
#: (tests/fem_solver/test_fem.py::test_serial_and_mpi_solves_agree: once in CI, once in 3 runs beside
#: three busy processes, then 0 in 20). MUMPS's code was not captured then; a workspace that
#: dynamic scheduling outgrows (INFOG(1) = -9) fits the load dependence, and this relaxation is the
#: remedy for it (memory only, not accuracy). A failed linear solve now names MUMPS's INFOG(1, 2).
MUMPS_WORKSPACE_RELAXATION = 100
#: after a damped line-search step the factorised Jacobian is kept (solver.line_search_reuse_ratio) for at
#: most this many iterations in a row: a Jacobian kept longer converges in so many more iterations that
#: the line search runs out of them (tests/fem_solver/test_stepping.py: cut-backs at the triangle's peak)
DAMPED_REUSE_ITERATIONS = 5
# ``contact.reach_m`` (a scene key, 0 = off): the obstacle's contact integral runs over the
# underside facets that overlap, along x in the reference configuration, the obstacle's footprint
# at rest widened by that much on both sides; the rest of the underside cannot reach it. On
# coin_pull (5 mm) the DEA and the coin move 1-2 mm against each other, and the 11 x 11 rule of
# ``resolved`` then covers 36 of the 72 underside facets (docs/fem_accuracy.md). Outside, the
# penalty and the friction are exactly zero, so the solution is the same to the bit; every record
# checks that no quadrature point outside touches the obstacle (:meth:`DEAProblem.check_reach`).

#: the problem's own facet tag of the underside facets out of the obstacle's reach (they keep
#: ``groups.DEA_CONTACT`` in the mesh; one tag object serves every ds of a form, as UFL requires)
OUT_OF_REACH = 100 + groups.DEA_CONTACT
UNDERSIDE = (groups.DEA_CONTACT, OUT_OF_REACH)


class ContactOutOfReach(RuntimeError):
    """A point of the underside outside the contact integral's facets touches the obstacle."""


@dataclass
class SolveResult:
    converged: bool
    reason: str
    iterations: int
    residual: float


def tip_element_length(scene) -> float:
    """Length along x of the DEA's element at the free end (m), where the contact acts: the
    uniform L / n, or the smallest of a graded mesh (``mesh.x_grading``, a geometric
    progression with clamp/tip ratio g over n elements)."""
    m = scene.mesh
    n = m.n_length * 2 ** m.level
    L, g = scene.dea.length_m, m.x_grading
    if g == 1.0 or n < 2:
        return L / n
    r = g ** (1.0 / (n - 1))
    return L * (r - 1.0) / (r ** n - 1.0)


class DEAProblem:
    """Quasi-static electro-hyperelastic DEA, optionally in frictional contact with an obstacle.

    Parameters
    ----------
    scene : deapull.scene.Scene
    mesh, cell_tags, facet_tags : the DEA mesh (``fem_solver.compat.read_mesh``)
    """

    def __init__(self, scene, mesh, cell_tags, facet_tags):
        self.scene, self.mesh, self.comm = scene, mesh, mesh.comm
        self.layout = layout(scene)
        sv = scene.solver
        self.mixed = sv.formulation == "mixed"
        self.coupled = sv.electrostatics == "coupled"
        self.has_voltage = scene.load.voltage_max_V > 0
        self.has_gravity = scene.gravity_m_s2 > 0
        self.obstacle = scene.coin or scene.stop

        order = scene.mesh.order
        ue = compat.element("Lagrange", mesh, order, shape=(3,))
        elements = [ue]
        if self.mixed:
            elements.append(compat.element("Lagrange", mesh, max(order - 1, 1)))
        if self.coupled:
            elements.append(compat.element("Lagrange", mesh, order))
        self.has_parts = len(elements) > 1          # mixed space (u, [p], [phi]) or plain u
        self.W = compat.function_space(mesh, compat.mixed_element(*elements) if self.has_parts else ue)
        self.w = dolfinx.fem.Function(self.W, name="state")
        self.w_old = dolfinx.fem.Function(self.W)
        self.w_older = dolfinx.fem.Function(self.W)
        self.w_oldest = self.w_older.x.array.copy()        # w_{n-2}, for the quadratic predictor only
        parts = ufl.split(self.w) if self.has_parts else (self.w,)
        old = ufl.split(self.w_old) if self.has_parts else (self.w_old,)
        self.parts = parts
        self.u, self.u_old = parts[0], old[0]
        self.p = parts[1] if self.mixed else None
        self.phi = parts[-1] if self.coupled else None

        self.voltage = dolfinx.fem.Constant(mesh, 0.0)
        self.X = dolfinx.fem.Constant(mesh, 0.0)
        self.X_old = dolfinx.fem.Constant(mesh, 0.0)
        self.dt = dolfinx.fem.Constant(mesh, 1.0)
        self.gravity_scale = dolfinx.fem.Constant(mesh, 1.0)

        qd = sv.quadrature_degree
        facet_tags = self._contact_reach(mesh, facet_tags)
        self.dx, self.ds = compat.integration_measures(mesh, cell_tags, facet_tags, qd)
        self.ds_contact = compat.facet_measure(mesh, facet_tags, groups.DEA_CONTACT, scene.contact.quadrature_degree,
                                               scene.contact.quadrature_rule)
        # a half model (z >= 0) carries half of every force on the obstacle
        self.symmetry_factor = 2.0 if scene.mesh.symmetry == "half_z" else 1.0
        self._tip_measure(qd)
        self._facet_tags = facet_tags
        # (points, cells) of each quadrature on first use (_positions_at): the contact's, its rule on the
        # underside facets out of the obstacle's reach, the table's
        self._contact_points = self._outside_points = self._table_points = None
        # the table's rule: Gauss–Lobatto on quadrilateral facets (points on the edges and corners, where
        # the DEA drapes onto the table); basix has no Lobatto rule on triangles, so tetrahedra get Gauss
        self.table_rule = "gauss_lobatto" if mesh.topology.cell_type == dolfinx.mesh.CellType.hexahedron else "gauss"
        self._build_forms(cell_tags, facet_tags)
        self._build_snes()

    # --- forms ---------------------------------------------------------------------

    def _contact_reach(self, mesh, facet_tags):
        """The facet tags with the underside facets beyond ``contact.reach_m`` of the
        obstacle's footprint (along x, reference configuration) retagged :data:`OUT_OF_REACH`:
        the contact integral runs over ``groups.DEA_CONTACT``, the table's over both."""
        reach = self.scene.contact.reach_m
        if self.obstacle is None or reach <= 0:
            return facet_tags
        lay = self.layout
        lo = lay.obstacle_center_x_m - lay.obstacle_radius_m - reach
        hi = lay.obstacle_center_x_m + lay.obstacle_radius_m + reach
        fdim = mesh.topology.dim - 1
        under = compat.facets_with_tag(facet_tags, groups.DEA_CONTACT)
        x = mesh.geometry.x[dolfinx.cpp.mesh.entities_to_geometry(mesh._mesh, fdim, under, False)][:, :, 0]
        far = under[(x.min(axis=1) > hi) | (x.max(axis=1) < lo)]
        values = facet_tags.values.copy()
        values[np.isin(facet_tags.indices, far)] = OUT_OF_REACH
        return dolfinx.mesh.meshtags(mesh, fdim, facet_tags.indices, values)

    def check_reach(self) -> None:
        """Raise :class:`ContactOutOfReach` when a quadrature point (the contact rule's) of an
        underside facet outside the contact integral touches the obstacle: the integral would
        miss that contact. Collective under MPI."""
        if self.contact is None:
            return
        local = float(np.max(self._obstacle_depth(self._positions_at("outside")), initial=0.0))
        deepest = self.comm.allreduce(local, op=MPI.MAX)
        if deepest > 0:
            raise ContactOutOfReach(
                f"the DEA's underside touches the obstacle {deepest * 1e6:.3g} um deep outside the contact "
                f"integral's facets (those within contact.reach_m = {self.scene.contact.reach_m * 1e3:g} mm of the "
                f"obstacle's footprint at rest): raise contact.reach_m, or 0 for the whole underside")

    def _tip_measure(self, qd):
        L = self.layout.length_m
        fdim = self.mesh.topology.dim - 1
        tip = dolfinx.mesh.locate_entities_boundary(self.mesh, fdim, lambda x: np.isclose(x[0], -L))
        tags = dolfinx.mesh.meshtags(self.mesh, fdim, np.sort(tip).astype(np.int32),
                                     np.ones(len(tip), dtype=np.int32))
        self.ds_tip = ufl.Measure("ds", domain=self.mesh, subdomain_data=tags, subdomain_id=1,
                                  metadata={"quadrature_degree": qd})

    def _build_forms(self, cell_tags, facet_tags):
        sc, d = self.scene, self.scene.dea
        u = self.u
        F = ufl.Identity(3) + ufl.grad(u)
        psi = materials.mixed_energy(F, self.p, d) if self.mixed else materials.displacement_energy(F, d)
        energy = psi * self.dx
        if self.has_voltage:
            eps = electro.permittivity(d)
            E0 = -ufl.grad(self.phi) if self.coupled else electro.nominal_field(self.voltage, d)
            energy += electro.electrostatic_energy(F, E0, eps) * self.dx(groups.ACTIVE)
        if self.has_gravity:
            energy += self.gravity_scale * d.density_kg_m3 * sc.gravity_m_s2 * u[1] * self.dx
        dw = ufl.TestFunction(self.W)
        v = ufl.split(dw)[0] if self.has_parts else dw
        self.contact, self._underside, self.penalty = None, None, None
        # a Constant, so that a hard step can be solved by continuation in it (Stepper._attempt)
        self.slip_reg = dolfinx.fem.Constant(self.mesh, float(sc.contact.slip_rate_regularisation_m_s))
        if self.obstacle is not None:
            lay = self.layout
            self.mu_t = dolfinx.fem.Constant(self.mesh, float(self.obstacle.mu_t))
            # a Constant, so that placement can raise a stiff penalty by continuation (Stepper.start)
            self.penalty = dolfinx.fem.Constant(self.mesh, float(sc.contact.penalty_N_m3))
            self.contact = contact.contact_terms(
                u, self.u_old, v, self.X, self.X_old, self.dt, self.ds_contact,
                center_x0=lay.obstacle_center_x_m, top_y=lay.obstacle_top_y_m, radius=lay.obstacle_radius_m,
                edge_radius=self.obstacle.edge_radius_m, mu=self.mu_t, penalty_N_m3=self.penalty,
                slip_rate_reg_m_s=self.slip_reg, edge_shape=self.obstacle.edge_shape)
            energy += self.contact.energy
        self.table = None
        if sc.table is not None:
            tb = sc.table
            self.ds_table = compat.facet_measure(self.mesh, facet_tags, UNDERSIDE, tb.quadrature_degree,
                                                 self.table_rule)
            self.mu_g = dolfinx.fem.Constant(self.mesh, float(tb.mu_g))
            self.table = table.table_terms(u, self.u_old, v, self.dt, self.ds_table, height_m=tb.height_m,
                                           mu=self.mu_g, penalty_N_m3=tb.penalty_N_m3,
                                           slip_rate_reg_m_s=self.slip_reg)
            energy += self.table.energy
        residual = ufl.derivative(energy, self.w, dw)
        if self.contact is not None:
            residual += self.contact.friction_residual
        if self.table is not None:
            residual += self.table.friction_residual
        jacobian = ufl.derivative(residual, self.w, ufl.TrialFunction(self.W))
        self.F_form, self.J_form = compat.form(residual), compat.form(jacobian)
        self.bcs = self._boundary_conditions(facet_tags, cell_tags)
        clamp = compat.facets_with_tag(facet_tags, groups.CLAMP)
        self._clamp_rows = [compat.owned_component_dofs(self.W, self.mesh, clamp, i, self.has_parts)
                            for i in (0, 1)]
        self._reaction_b = compat.create_vector(self.F_form)
        # what F depends on besides the unknowns: a residual's clamp-row sums are reused only while
        # these and the unknowns are those it was assembled at (clamp_reaction)
        self._F_inputs = ([c for c in residual.constants()],
                          [c for c in residual.coefficients() if c is not self.w])
        self._last_reaction = None   # (fingerprint, local clamp-row sums of F) of the last residual assembled

        self.tip_area = compat.assemble_scalar(compat.form(1.0 * self.ds_tip), self.comm)
        self.tip_forms = [compat.form(u[i] * self.ds_tip) for i in range(3)]
        self.volume_batch = compat.ScalarBatch([abs(ufl.det(F) - 1) * self.dx, (ufl.det(F) - 1) * self.dx], self.mesh)
        self.volume = compat.assemble_scalar(compat.form(1.0 * self.dx), self.comm)
        if self.contact is not None:
            # the record's contact integrals, each group in one assembly (compat.ScalarBatch)
            self.force_batch = compat.ScalarBatch([self.contact.Fx, self.contact.Fy], self.mesh)
            x = ufl.SpatialCoordinate(self.mesh) + u
            pn = self.contact.pressure
            self.centre_batch = compat.ScalarBatch([pn * self.ds_contact, pn * x[0] * self.ds_contact,
                                                    pn * x[2] * self.ds_contact, pn * abs(x[2]) * self.ds_contact],
                                                   self.mesh)
            probe = self._patch_probe(dolfinx.fem.Constant(self.mesh, 0.0))
            self.probe_batch = compat.ScalarBatch([probe.pressure, probe.pressure_vx, probe.normal_x], self.mesh)
            self._drag_batches = {}
        if self.table is not None:
            self.table_forms = (compat.form(self.table.Rx), compat.form(self.table.Ry))

    def _boundary_conditions(self, facet_tags, cell_tags):
        clamp = compat.facets_with_tag(facet_tags, groups.CLAMP)
        sub = 0 if self.has_parts else None
        bcs = [compat.dirichlet_zero(self.W, self.mesh, clamp, subspace=sub)]
        if self.scene.mesh.symmetry == "half_z":
            mid = compat.facets_with_tag(facet_tags, groups.SYMMETRY)
            bcs.append(compat.dirichlet_zero_component(self.W, self.mesh, mid, 2, self.has_parts))
        if self.coupled:
            k = len(self.parts) - 1
            bottom = compat.facets_with_tag(facet_tags, groups.ELECTRODE_BOTTOM)
            top = compat.facets_with_tag(facet_tags, groups.ELECTRODE_TOP)
            bcs.append(compat.dirichlet_zero(self.W, self.mesh, bottom, subspace=k))
            passive = cell_tags.indices[cell_tags.values == groups.PASSIVE]
            bcs.append(compat.dirichlet_zero_cells(self.W, self.mesh, passive, subspace=k))
            _, collapsed = compat.locate_dofs_on_facets(self.W, self.mesh, top, subspace=k)
            self.phi_top = dolfinx.fem.Function(collapsed)
            bcs.append(compat.dirichlet_value(self.W, self.mesh, top, self.phi_top, subspace=k))
        return bcs

    # --- Newton --------------------------------------------------------------------

    def _build_snes(self):
        sv = self.scene.solver
        self.b = compat.create_vector(self.F_form)
        self.A = compat.create_matrix(self.J_form)
        self.x = self.w.vector.copy()
        snes = PETSc.SNES().create(self.comm)
        prefix = f"deapull_{id(self)}_"
        snes.setOptionsPrefix(prefix)
        opts = PETSc.Options()
        self._options = {"snes_linesearch_type": "basic", "snes_divergence_tolerance": -1}
        for key, value in self._options.items():
            opts[prefix + key] = value
        snes.setType("newtonls")
        snes.setFunction(self._eval_F, self.b)
        snes.setJacobian(self._eval_J, self.A)
        snes.setTolerances(rtol=sv.newton_rtol, atol=sv.newton_atol, stol=0.0, max_it=sv.newton_max_it)
        snes.setConvergenceTest(self._converged)
        ksp = snes.getKSP()
        ksp.setType("preonly")
        pc = ksp.getPC()
        pc.setType("lu")
        package = self.factor_package()
        pc.setFactorSolverType(package)
        snes.setErrorIfNotConverged(False)
        snes.setFromOptions()
        for key in self._options:
            del opts[prefix + key]
        if package == "mumps":
            # read when the factor matrix is made (the first solve), so it stays in the database
            opts[prefix + "mat_mumps_icntl_14"] = MUMPS_WORKSPACE_RELAXATION
        self.snes = snes
        self._jacobian_ready, self._last_fnorm, self._placing, self.line_search = False, 0.0, False, "basic"
        self._f_evals = self._f_evals_at_J = 0     # residuals assembled, and at the last Jacobian call
        self._kept_damped = 0                     # damped iterations in a row on the kept Jacobian
        self._first_fnorm, self._best_fnorm, self._best_it, self.stalled = 0.0, 0.0, 0, False
        self.jacobian_assemblies = self.jacobian_reuses = 0

    def _converged(self, snes, it, norms):
        """PETSc's default test on the residual (``atol``, ``rtol`` against the first residual,
        ``max_it``, NaN), plus a stall: no residual below :data:`STALL_FACTOR` × the smallest so far
        in :data:`STALL_ITERATIONS` iterations ends the solve as diverged (``stalled``). Full Newton
        steps at a friction reversal cycle between a few residuals for all of ``max_it`` iterations,
        each with a fresh Jacobian; a damped line search that converges slowly sets a new smallest
        residual every iteration and is not stopped."""
        fnorm = norms[2]
        R = PETSc.SNES.ConvergedReason
        if it == 0:
            self._first_fnorm, self._best_fnorm, self._best_it, self.stalled = fnorm, fnorm, 0, False
        if not math.isfinite(fnorm):
            return R.DIVERGED_FNORM_NAN
        rtol, atol, _, max_it = snes.getTolerances()
        if fnorm < atol:
            return R.CONVERGED_FNORM_ABS
        if it > 0 and fnorm <= rtol * self._first_fnorm:
            return R.CONVERGED_FNORM_RELATIVE
        if fnorm < STALL_FACTOR * self._best_fnorm:
            self._best_fnorm, self._best_it = fnorm, it
        elif it - self._best_it >= STALL_ITERATIONS and not self._placing:
            self.stalled = True
            return R.DIVERGED_MAX_IT
        if it >= max_it:
            return R.DIVERGED_MAX_IT
        return R.ITERATING

    def set_line_search(self, kind: str) -> None:
        """The line search of the Newton solves: ``basic`` (full steps, the default) or a PETSc
        type such as ``bt`` (backtracking), named by ``line_search``. Set through this SNES's own
        options prefix, which is cleared again (this petsc4py has no SNESLineSearch object)."""
        key = self.snes.getOptionsPrefix() + "snes_linesearch_type"
        opts = PETSc.Options()
        opts[key] = kind
        self.snes.setFromOptions()
        del opts[key]
        self.line_search = kind

    @contextlib.contextmanager
    def newton_max_it(self, max_it: int):
        """Newton's iteration cap set to ``max_it`` inside the block (the scene's outside)."""
        self.snes.setTolerances(max_it=max_it)
        try:
            yield
        finally:
            self.snes.setTolerances(max_it=self.scene.solver.newton_max_it)

    @contextlib.contextmanager
    def friction_regularisation(self, scale: float):
        """The friction's slip-rate regularisation ε_v (of the coin and the table) times ``scale``
        inside the block (the scene's outside)."""
        self.slip_reg.value = scale * self.scene.contact.slip_rate_regularisation_m_s
        try:
            yield
        finally:
            self.slip_reg.value = self.scene.contact.slip_rate_regularisation_m_s

    @contextlib.contextmanager
    def placement_newton(self):
        """Newton as the placement's continuation needs it inside the block: a fresh Jacobian at every
        iteration (``solver.jacobian_reuse_ratio`` outside) and no stall test (the continuation caps
        the iterations and cuts its step; first touch wanders before it converges)."""
        self._placing = True
        try:
            yield
        finally:
            self._placing = False

    def factor_package(self) -> str:
        """``solver.linear_solver``, or mumps when the mesh is split over ranks and the
        chosen package is serial."""
        chosen = self.scene.solver.linear_solver
        if self.comm.size > 1 and chosen not in PARALLEL_FACTOR_PACKAGES:
            if self.comm.rank == 0:
                log.info("solver.linear_solver = %r is serial; using mumps on %d ranks", chosen, self.comm.size)
            return "mumps"
        return chosen

    def _eval_F(self, snes, x, b):
        x.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        x.copy(self.w.vector)
        self.w.vector.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        self._f_evals += 1
        if self.coupled:
            compat.assemble_residual(b, self.F_form, self.J_form, self.bcs, x, lifting=True)
            return
        # without lifting the clamp rows hold the reaction before set_bc: kept with the state they
        # belong to, so the record's force balance (clamp_reaction) needs no assembly of its own
        sums = compat.assemble_residual(b, self.F_form, self.J_form, self.bcs, x, lifting=False,
                                        rows=self._clamp_rows)
        self._last_reaction = (self._fingerprint(x.array_r), sums)

    def _fingerprint(self, unknowns) -> np.ndarray:
        """Everything the residual F depends on, as one array: the unknowns, the constants' values
        and the other coefficients' (the previous step's state)."""
        constants, coefficients = self._F_inputs
        return np.concatenate([unknowns, *(np.ravel(c.value) for c in constants),
                               *(c.x.array for c in coefficients)])

    def _eval_J(self, snes, x, A, P):
        """Assemble the Jacobian, or keep the factorised one while Newton still converges.

        With ``solver.jacobian_reuse_ratio = r > 0`` the last assembled (and factorised)
        Jacobian starts every solve and is kept — across iterations and steps — as long as
        each iteration cuts the residual by at least the factor r; PETSc then skips the
        refactorisation since the matrix is unchanged. A slower iteration, or a failed
        solve, triggers a fresh Jacobian.

        While a line search damps Newton's steps (the last one took more than one residual: a
        friction's onset or reversal, after :meth:`set_line_search`), r is
        ``solver.line_search_reuse_ratio``: those iterations cut the residual by ≈ 0.9 each with a
        fresh Jacobian or a kept one, since the direction, not the Jacobian, limits them, and a fresh
        one (assembly and LU) costs tens of kept iterations. At most :data:`DAMPED_REUSE_ITERATIONS`
        damped iterations in a row keep it.
        Undamped steps under the line search keep ``solver.jacobian_reuse_ratio``: a kept Jacobian that
        converges slowly there is stale
        (tests/fem_solver/test_stepping.py::test_a_line_search_keeps_its_jacobian_longer_and_lands_on_the_same_path).
        """
        it, fnorm = snes.getIterationNumber(), snes.getFunctionNorm()
        sv = self.scene.solver
        # a full step costs the line search one residual, a damped one two or more
        damped = self.line_search != "basic" and it > 0 and self._f_evals - self._f_evals_at_J > 1
        self._f_evals_at_J = self._f_evals
        r = 0.0 if self._placing else (sv.line_search_reuse_ratio if damped else sv.jacobian_reuse_ratio)
        reuse = r > 0 and self._jacobian_ready and (it == 0 or fnorm <= r * self._last_fnorm)
        if damped:      # kept for at most DAMPED_REUSE_ITERATIONS in a row
            reuse = reuse and self._kept_damped < DAMPED_REUSE_ITERATIONS
            self._kept_damped = self._kept_damped + 1 if reuse else 0
        self._last_fnorm = fnorm
        if reuse:
            self.jacobian_reuses += 1
            return
        compat.assemble_jacobian(A, self.J_form, self.bcs)
        self._jacobian_ready = True
        self.jacobian_assemblies += 1

    def set_load(self, voltage: float, X: float, dt: float) -> None:
        """Voltage on the films, the obstacle's x displacement and the step for the next solve."""
        self.voltage.value = voltage
        self.X.value = X
        self.dt.value = dt
        if self.coupled:
            self.phi_top.x.array[:] = electro.stack_voltage(voltage, self.scene.dea)

    def enable_friction(self, on: bool) -> None:
        """Switch DEA–obstacle friction on or off (off for the initial placement under gravity)."""
        if self.contact is not None:
            self.mu_t.value = float(self.obstacle.mu_t) if on else 0.0
        if self.table is not None:
            self.mu_g.value = float(self.scene.table.mu_g) if on else 0.0

    def solve(self) -> SolveResult:
        """Newton from the current state; the state is left at the last iterate."""
        self.w.vector.copy(self.x)
        self.snes.solve(None, self.x)
        reason = self.snes.getConvergedReason()
        if reason <= 0:
            self._jacobian_ready = False   # a failed attempt starts over from a fresh Jacobian
        self.x.copy(self.w.vector)
        self.w.x.scatter_forward()
        finite = bool(self.comm.allreduce(np.isfinite(self.w.x.array).all(), op=MPI.LAND))
        rnorm = self.snes.getFunctionNorm()
        ok = reason > 0 and finite
        name = SNES_REASONS.get(reason, str(reason)) if finite else "DIVERGED_FNORM_NAN"
        if self.stalled and reason <= 0:
            name = (f"DIVERGED_STALLED (no residual below {STALL_FACTOR:g} x the smallest in {STALL_ITERATIONS} "
                    "iterations)")
        if name == "DIVERGED_LINEAR_SOLVE":
            name += self._factor_error()
        return SolveResult(ok, name, self.snes.getIterationNumber(), float(rnorm))

    def _factor_error(self) -> str:
        """MUMPS's own error code after a failed linear solve (" (MUMPS INFOG(1) = -9, INFOG(2) =
        ...)"), or "" for another package or when MUMPS reports none."""
        pc = self.snes.getKSP().getPC()
        if pc.getFactorSolverType() != "mumps":
            return ""
        try:
            factor = pc.getFactorMatrix()
            info1, info2 = factor.getMumpsInfog(1), factor.getMumpsInfog(2)
        except PETSc.Error:
            return ""
        return f" (MUMPS INFOG(1) = {info1}, INFOG(2) = {info2})" if info1 < 0 else ""

    # --- state ---------------------------------------------------------------------

    def predict(self, weights) -> None:
        """Extrapolation from the last accepted states: w = a w_n + b w_{n−1} [+ c w_{n−2}] for
        ``weights`` = (a, b[, c]) (the stepper's Lagrange weights; linear: (1 + r, −r))."""
        a, b, *c = weights
        self.w.x.array[:] = a * self.w_old.x.array + b * self.w_older.x.array
        if c and c[0] != 0.0:
            self.w.x.array[:] += c[0] * self.w_oldest

    def accept(self) -> None:
        self.w_oldest[:] = self.w_older.x.array
        self.w_older.x.array[:] = self.w_old.x.array
        self.w_old.x.array[:] = self.w.x.array
        self.X_old.value = float(self.X.value)

    def restore(self) -> None:
        """Back to the last accepted state (after a failed attempt)."""
        self.w.x.array[:] = self.w_old.x.array
        self.X.value = float(self.X_old.value)

    # --- outputs -------------------------------------------------------------------

    def obstacle_forces(self) -> tuple[float, float]:
        """(Fx, Fy): force of the DEA on the obstacle, N (Fy pressing, positive downward)."""
        if self.contact is None:
            return 0.0, 0.0
        Fx, Fy = self.symmetry_factor * self.force_batch.values(self.comm)
        return float(Fx), float(Fy)

    def obstacle_forces_from_reaction(self) -> tuple[float, float]:
        """(Fx, Fy) of the DEA on the obstacle from the clamp reaction, not from the contact
        integral: the DEA is quasi-static, so the obstacle's force on it balances the clamp
        reaction r and its weight W. With the residual R assembled on every row (Dirichlet
        rows not zeroed), r is the sum of R over the clamp rows, and

            Fx = r_x + R_x,        Fy = W − r_y − R_y       (Fy positive downward)

        with R the table's reaction on the DEA (:meth:`table_reaction`, 0 without a table),
        up to the sum of R over the free rows, i.e. the Newton residual (:meth:`clamp_reaction`).
        """
        if self.contact is None:
            return 0.0, 0.0
        rx, ry = self.clamp_reaction()
        Rx, Ry = self.table_reaction()
        return rx + Rx, self.weight() - ry - Ry

    def clamp_reaction(self) -> tuple[float, float]:
        """(r_x, r_y): force of the clamp on the DEA, N, from the residual assembled on every row
        (Dirichlet rows not zeroed): the sum of R over the clamp rows. Read off the solve's last
        residual when the unknowns, the constants and the previous state are those it was assembled
        at (after a converged solve, before ``accept()``), else one vector assembly."""
        k = self.symmetry_factor
        state, sums = self._last_reaction if self._last_reaction is not None else (None, None)
        if state is None or not np.array_equal(state, self._fingerprint(self.w.vector.array_r)):
            b = self._reaction_b
            compat.assemble_vector_free(b, self.F_form)
            sums = [float(b.array_r[rows].sum()) for rows in self._clamp_rows]
        return tuple(k * self.comm.allreduce(v, op=MPI.SUM) for v in sums)

    def weight(self) -> float:
        """The DEA's weight at the current gravity scale, N (whole model)."""
        if not self.has_gravity:
            return 0.0
        return (self.symmetry_factor * self.scene.dea.density_kg_m3 * self.scene.gravity_m_s2
                * float(self.gravity_scale.value) * self.volume)

    def table_reaction(self) -> tuple[float, float]:
        """(R_x, R_y): force of the table on the DEA, N (R_y upward); (0, 0) without a table."""
        if self.table is None:
            return 0.0, 0.0
        k = self.symmetry_factor
        return tuple(k * compat.assemble_scalar(f, self.comm) for f in self.table_forms)

    def contact_centre(self) -> tuple[float, float, float]:
        """(x, z, |z|) of the DEA–obstacle contact: the current positions on the underside weighted
        by the normal traction (m; z = 0 for a half model, whose mirror image balances it), and
        the traction-weighted mean of |z|, how far from the mid-plane z = 0 the patch sits (the
        same for a half and a whole model; the coin's two patches straddle the DEA's edges);
        NaN when nothing touches."""
        if self.contact is None:
            return math.nan, math.nan, math.nan
        total, mx, mz, mabs = (float(v) for v in self.centre_batch.values(self.comm))
        if not total > 0:
            return math.nan, math.nan, math.nan
        return mx / total, (0.0 if self.symmetry_factor != 1.0 else mz / total), mabs / total

    def patch_probe(self, shares) -> tuple[float, float, list[float]]:
        """The contact patch's side of the friction after a solved step, before it is accepted:
        (v̄, N_x, drags). v̄ is the traction-weighted mean x velocity of the DEA's touching points
        (m/s), N_x the x force of the normal traction on the obstacle (N), and drags[i] the x force
        the friction would put on an obstacle moving at ``shares[i]`` × v̄, per unit μ_t (N). Forces
        are of the whole model (a half model's doubled); all 0 when nothing touches."""
        if self.contact is None:
            return 0.0, 0.0, [0.0] * len(shares)
        k = self.symmetry_factor
        total, pressure_vx, normal_x = (float(v) for v in self.probe_batch.values(self.comm))
        if not total > 0:
            return 0.0, 0.0, [0.0] * len(shares)
        vx = pressure_vx / total
        drags = []
        if shares:
            if len(shares) not in self._drag_batches:
                velocities = [dolfinx.fem.Constant(self.mesh, 0.0) for _ in shares]
                batch = compat.ScalarBatch([self._patch_probe(c).drag for c in velocities], self.mesh)
                self._drag_batches[len(shares)] = (velocities, batch)
            velocities, batch = self._drag_batches[len(shares)]
            for c, share in zip(velocities, shares):
                c.value = share * vx
            drags = [k * float(d) for d in batch.values(self.comm)]
        return vx, k * normal_x, drags

    def _patch_probe(self, coin_velocity) -> contact.PatchProbe:
        """The patch probe's forms with the obstacle moving at the Constant ``coin_velocity`` (m/s)."""
        lay = self.layout
        return contact.patch_probe(
            self.u, self.u_old, self.X, self.dt, self.ds_contact, coin_velocity,
            center_x0=lay.obstacle_center_x_m, top_y=lay.obstacle_top_y_m, radius=lay.obstacle_radius_m,
            edge_radius=self.obstacle.edge_radius_m, penalty_N_m3=self.penalty,
            slip_rate_reg_m_s=self.slip_reg, edge_shape=self.obstacle.edge_shape)

    def tip_displacement(self) -> np.ndarray:
        """Mean displacement of the free-end face (m)."""
        mean = np.array([compat.assemble_scalar(f, self.comm) for f in self.tip_forms]) / self.tip_area
        if self.symmetry_factor != 1.0:
            mean[2] = 0.0   # u_z is odd in z: its mean over the whole face is 0
        return mean

    def max_penetration(self) -> float:
        """Largest penetration of the DEA's underside nodes into the obstacle (m): the signed
        distance of fem_solver/contact.py (cylinder with the rounded rim), evaluated at nodes."""
        if self.contact is None:
            return 0.0
        lay = self.layout
        if self._underside is None:
            coords, dofs = compat.displacement_dofs(self.W, self.has_parts)
            under = np.isclose(coords[:, 1], lay.y_bottom_m)
            self._underside = (coords[under], dofs[under])
        coords, dofs = self._underside
        x = coords + self.w.x.array[dofs]
        rho = np.hypot(x[:, 0] - lay.obstacle_center_x_m - float(self.X.value), x[:, 2])
        depth = -contact.rounded_cylinder_distance(rho, x[:, 1], lay.obstacle_top_y_m, lay.obstacle_radius_m,
                                                   self.obstacle.edge_radius_m, self.obstacle.edge_shape)
        local = float(np.max(depth, initial=0.0))
        return self.comm.allreduce(local, op=MPI.MAX)

    def _positions_at(self, which: str) -> np.ndarray:
        """Current positions (n, 3) of this rank's quadrature points of the obstacle's
        (``which = "contact"``) or the table's (``"table"``) integral on the underside, or of the
        obstacle's rule on the underside facets out of its reach (``"outside"``)."""
        attr = f"_{which}_points"
        if getattr(self, attr) is None:
            if which in ("contact", "outside"):
                sc = self.scene.contact
                degree, rule = sc.quadrature_degree, sc.quadrature_rule
                tag = groups.DEA_CONTACT if which == "contact" else OUT_OF_REACH
                facets = compat.facets_with_tag(self._facet_tags, tag)
            else:
                degree, rule = self.scene.table.quadrature_degree, self.table_rule
                facets = np.concatenate([compat.facets_with_tag(self._facet_tags, t) for t in UNDERSIDE])
            points, cells = compat.facet_quadrature_points(self.mesh, facets, degree, rule)
            setattr(self, attr, compat.PointEvaluator(self.w, points, cells, 0 if self.has_parts else None))
        ev = getattr(self, attr)
        return ev.points + ev.values(self.w)

    def _obstacle_depth_at_points(self) -> np.ndarray:
        return self._obstacle_depth(self._positions_at("contact"))

    def _obstacle_depth(self, x: np.ndarray) -> np.ndarray:
        """Penetration (m, > 0 inside) of the current positions ``x`` (n, 3) into the obstacle."""
        if not len(x):
            return np.zeros(0)
        lay = self.layout
        rho = np.hypot(x[:, 0] - lay.obstacle_center_x_m - float(self.X.value), x[:, 2])
        return -contact.rounded_cylinder_distance(rho, x[:, 1], lay.obstacle_top_y_m, lay.obstacle_radius_m,
                                                  self.obstacle.edge_radius_m, self.obstacle.edge_shape)

    def contact_points(self) -> tuple[np.ndarray, np.ndarray]:
        """This rank's quadrature points of the DEA–obstacle contact integral: their current
        positions (n, 3) and their penetrations into the obstacle (n,; m, > 0 where they touch)."""
        return self._positions_at("contact"), self._obstacle_depth_at_points()

    def max_penetration_at_points(self) -> float:
        """Largest penetration into the obstacle (m) at the contact integral's own
        quadrature points on the DEA's underside — the only places where the penalty and the
        friction act (``contact.quadrature_degree`` / ``quadrature_rule``)."""
        return self.contact_point_stats()[1]

    def contact_point_stats(self) -> tuple[int, float]:
        """(the number of the contact integral's quadrature points that touch the obstacle, i.e. carry
        Fx and Fy, in the modelled mesh; :meth:`max_penetration_at_points`) from one evaluation of
        those points (the record takes both)."""
        if self.contact is None:
            return 0, 0.0
        depth = self._obstacle_depth_at_points()
        n = int(self.comm.allreduce(int(np.count_nonzero(depth > 0)), op=MPI.SUM))
        return n, self.comm.allreduce(float(np.max(depth, initial=0.0)), op=MPI.MAX)

    def table_penetration(self) -> float:
        """Largest penetration of the DEA's underside into the table (m) at the table integral's
        quadrature points; 0 without a table."""
        if self.table is None:
            return 0.0
        x = self._positions_at("table")
        local = float(np.max(self.scene.table.height_m - x[:, 1], initial=0.0)) if len(x) else 0.0
        return self.comm.allreduce(local, op=MPI.MAX)

    def volume_changes(self) -> tuple[float, float]:
        """(mean |J − 1|, (∫ J dX − V₀) / V₀): the volume-averaged |J − 1| (0 for an exactly
        incompressible solution) and the DEA's relative change of volume, in one assembly."""
        mean_abs, net = self.volume_batch.values(self.comm) / self.volume
        return float(mean_abs), float(net)

    def num_dofs(self) -> int:
        return self.W.dofmap.index_map.size_global * self.W.dofmap.index_map_bs
