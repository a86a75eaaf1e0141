"""Every dolfinx-version-specific call (written against dolfinx 0.5.2, Debian 12).

A move to a newer dolfinx (``functionspace``, ``gmshio.read_from_msh`` returning a
named tuple, ``create_matrix`` signatures …) should only touch this module.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import basix
import dolfinx
import dolfinx.fem.petsc
import gmsh
import numpy as np
import scipy.sparse
import ufl
from dolfinx.io import gmshio
from mpi4py import MPI
from petsc4py import PETSc

from deapull.errors import InputError
from deapull.meshing import groups


class MeshFileError(InputError):
    """A mesh file that is missing or lacks the groups the solver needs."""


@dataclass
class SceneMesh:
    """A scene's ``.msh`` as read once: the DEA mesh for dolfinx, and the volume of each
    separately measured group (``volumes_m3``, e.g. the coin's, for its mass)."""
    mesh: dolfinx.mesh.Mesh
    cell_tags: dolfinx.mesh.MeshTags
    facet_tags: dolfinx.mesh.MeshTags
    volumes_m3: dict = field(default_factory=dict)


def read_mesh(path: str | Path, comm=MPI.COMM_WORLD, volumes=groups.DEA_VOLUMES):
    """Read the named volume groups of a scene ``.msh`` into dolfinx, with their tags.

    Returns
    -------
    (mesh, cell_tags, facet_tags)
    """
    read = read_scene_mesh(path, comm, volumes, measured=())
    return read.mesh, read.cell_tags, read.facet_tags


def read_scene_mesh(path: str | Path, comm=MPI.COMM_WORLD, volumes=groups.DEA_VOLUMES,
                    measured=("coin",)) -> SceneMesh:
    """Read a scene ``.msh`` once: the cells of ``volumes`` with their tags into dolfinx, and
    the volume of each group of ``measured`` that the file has (assembled by dolfinx on the
    group's own mesh, of the file's element order: the curved coin rim counts).

    Rank 0 reads the file with gmsh and keeps the cells of ``volumes`` and the tagged
    facets that lie on them (gmsh's own ``removePhysicalGroups`` fails on merged files
    in gmsh 4.8, so the selection is done on the arrays); dolfinx then distributes the
    meshes over ``comm``.
    """
    path = Path(path)
    data, error, extra = None, None, {}
    if comm.rank == 0:
        if not path.is_file():
            error = "not found (run `deapull mesh` first)"
        else:
            gmsh.initialize()
            gmsh.option.setNumber("General.Terminal", 0)
            try:
                gmsh.merge(str(path))
                data, error = _extract(volumes)
                present = {groups.NAMES.get(tag) for _, tag in gmsh.model.getPhysicalGroups(3)}
                extra = {name: _extract((name,))[0] for name in measured if name in present}
            finally:
                gmsh.finalize()
    error = comm.bcast(error, root=0)
    if error:
        raise MeshFileError(f"mesh file {str(path)!r}: {error}")
    mesh, ct, ft = _distribute(data, comm)
    volumes_m3 = {}
    for name in comm.bcast(sorted(extra), root=0):
        part, _, _ = _distribute(extra.get(name), comm)
        volumes_m3[name] = assemble_scalar(form(1.0 * ufl.dx(domain=part)), comm)
    return SceneMesh(mesh, ct, ft, volumes_m3)


def _distribute(data, comm):
    """The dolfinx mesh and its (cell, facet) tags from :func:`_extract`'s arrays on rank 0."""
    cell_id, n_nodes, facet_nodes = comm.bcast(data[:3] if comm.rank == 0 else None, root=0)
    if comm.rank == 0:
        x, cells, cell_values, facets, facet_values = data[3:]
    else:
        x, cells, cell_values = np.empty((0, 3)), np.empty((0, n_nodes), np.int64), np.empty(0, np.int32)
        facets, facet_values = np.empty((0, facet_nodes), np.int64), np.empty(0, np.int32)
    domain = gmshio.ufl_mesh(cell_id, 3)
    cell_type = dolfinx.cpp.mesh.to_type(str(domain.ufl_cell()))
    cells = cells[:, gmshio.cell_perm_array(cell_type, n_nodes)]
    mesh = dolfinx.mesh.create_mesh(comm, cells, x, domain)
    tdim = mesh.topology.dim
    ents, vals = dolfinx.cpp.io.distribute_entity_data(mesh._mesh, tdim, cells, cell_values)
    mesh.topology.create_connectivity(tdim, 0)
    ct = dolfinx.mesh.meshtags_from_entities(mesh, tdim, dolfinx.cpp.graph.AdjacencyList_int32(ents),
                                             vals.astype(np.int32))
    facet_type = dolfinx.cpp.mesh.cell_entity_type(cell_type, tdim - 1, 0)
    facets = facets[:, gmshio.cell_perm_array(facet_type, facet_nodes)]
    ents, vals = dolfinx.cpp.io.distribute_entity_data(mesh._mesh, tdim - 1, facets, facet_values)
    mesh.topology.create_connectivity(tdim - 1, tdim)
    ft = dolfinx.mesh.meshtags_from_entities(mesh, tdim - 1, dolfinx.cpp.graph.AdjacencyList_int32(ents),
                                             vals.astype(np.int32))
    ct.name, ft.name = "cell_tags", "facet_tags"
    return mesh, ct, ft


def _elements_of_group(dim, tag):
    types, nodes = set(), []
    for entity in gmsh.model.getEntitiesForPhysicalGroup(dim, tag):
        etypes, _, enodes = gmsh.model.mesh.getElements(dim, entity)
        for et, nd in zip(etypes, enodes):
            n = gmsh.model.mesh.getElementProperties(et)[3]
            types.add(int(et))
            nodes.append(np.asarray(nd, dtype=np.int64).reshape(-1, n))
    return types, nodes


def _extract(volumes):
    """Arrays of the wanted volumes and of the facets on them, nodes renumbered from 0."""
    present = {tag for _, tag in gmsh.model.getPhysicalGroups(3)}
    wanted = [groups.VOLUMES[v] for v in volumes]
    missing = [groups.NAMES[t] for t in wanted if t not in present]
    if missing:
        have = ", ".join(groups.NAMES.get(t, str(t)) for t in sorted(present)) or "none"
        return None, f"physical volume(s) {', '.join(missing)} missing; present: {have}"
    cell_types, cell_blocks, cell_values = set(), [], []
    for tag in wanted:
        types, blocks = _elements_of_group(3, tag)
        cell_types |= types
        cell_blocks += blocks
        cell_values += [np.full(len(b), tag, np.int32) for b in blocks]
    if len(cell_types) != 1:
        return None, f"volumes {', '.join(volumes)} mix cell types {sorted(cell_types)}; dolfinx needs one"
    cells = np.vstack(cell_blocks)
    used = np.unique(cells)
    facet_types, facet_blocks, facet_values = set(), [], []
    for _, tag in gmsh.model.getPhysicalGroups(2):
        types, blocks = _elements_of_group(2, tag)
        for b in blocks:
            b = b[np.all(np.isin(b, used), axis=1)]
            if len(b):
                facet_blocks.append(b)
                facet_values.append(np.full(len(b), tag, np.int32))
                facet_types |= types
    node_tags, coords, _ = gmsh.model.mesh.getNodes()
    coords = np.asarray(coords).reshape(-1, 3)
    lookup = np.full(int(node_tags.max()) + 1, -1, np.int64)
    lookup[node_tags] = np.arange(len(node_tags))
    x = coords[lookup[used]]
    renumber = np.full(int(node_tags.max()) + 1, -1, np.int64)
    renumber[used] = np.arange(len(used))
    cell_id = cell_types.pop()
    n_facet_nodes = facet_blocks[0].shape[1] if facet_blocks else 0
    facets = renumber[np.vstack(facet_blocks)] if facet_blocks else np.empty((0, 0), np.int64)
    fvals = np.concatenate(facet_values) if facet_values else np.empty(0, np.int32)
    return (cell_id, cells.shape[1], n_facet_nodes, x, renumber[cells], np.concatenate(cell_values),
            facets, fvals), None


def cell_degree(mesh) -> int:
    return mesh.geometry.cmap.degree


def element(family: str, mesh, degree: int, shape=None):
    """A basix-backed UFL element on the mesh's cell (``shape=(3,)`` for vectors)."""
    cell = mesh.ufl_cell().cellname()
    if shape is None:
        return ufl.FiniteElement(family, cell, degree)
    return ufl.VectorElement(family, cell, degree, dim=shape[0])


def function_space(mesh, ufl_element):
    return dolfinx.fem.FunctionSpace(mesh, ufl_element)


def mixed_element(*elements):
    return ufl.MixedElement(list(elements))


def locate_dofs_on_facets(space, mesh, facets, subspace=None):
    """Dofs of ``space`` (or its sub-space) on the given facets; returns (dofs, collapsed space)."""
    fdim = mesh.topology.dim - 1
    if subspace is None:
        return dolfinx.fem.locate_dofs_topological(space, fdim, facets), space
    sub = space.sub(subspace)
    collapsed, _ = sub.collapse()
    dofs = dolfinx.fem.locate_dofs_topological((sub, collapsed), fdim, facets)
    return dofs, collapsed


def dirichlet_zero(space, mesh, facets, subspace=None):
    """Homogeneous Dirichlet condition on facets (all components of the sub-space)."""
    dofs, collapsed = locate_dofs_on_facets(space, mesh, facets, subspace)
    zero = dolfinx.fem.Function(collapsed)
    if subspace is None:
        return dolfinx.fem.dirichletbc(zero, dofs)
    return dolfinx.fem.dirichletbc(zero, dofs, space.sub(subspace))


def dirichlet_zero_cells(space, mesh, cells, subspace):
    """Homogeneous Dirichlet condition on every dof of a sub-space inside the given cells."""
    sub = space.sub(subspace)
    collapsed, _ = sub.collapse()
    dofs = dolfinx.fem.locate_dofs_topological((sub, collapsed), mesh.topology.dim, cells)
    return dolfinx.fem.dirichletbc(dolfinx.fem.Function(collapsed), dofs, sub)


def displacement_dofs(space, mixed: bool):
    """Node coordinates (n, 3) of the displacement field and the indices (n, 3) of its dofs
    in the (mixed) space's local array, for reading nodal displacements without a copy."""
    if mixed:
        collapsed, parent = space.sub(0).collapse()
        parent = np.asarray(parent)
    else:
        collapsed = space
        parent = np.arange(len(space.tabulate_dof_coordinates()) * 3)
    return collapsed.tabulate_dof_coordinates(), parent.reshape(-1, 3)


def dirichlet_value(space, mesh, facets, value: dolfinx.fem.Function, subspace):
    dofs, _ = locate_dofs_on_facets(space, mesh, facets, subspace)
    return dolfinx.fem.dirichletbc(value, dofs, space.sub(subspace))


#: the C compiler's flags for the forms' kernels (FFCx through CFFI), unless the environment variable
#: :data:`FORM_CFLAGS_ENV` gives others. Against dolfinx's own ``-O2 -g0`` the data fidelity's Jacobian
#: assembles in ≈ 0.8 of the time and its residual in ≈ 0.5 (``make bench BENCH=fem`` runs C3 both
#: ways). Fast math without ``-ffinite-math-only``: a NaN or an Inf still reaches the solver's checks.
FORM_CFLAGS = "-O3 -march=native -ffast-math -fno-finite-math-only -g0"
FORM_CFLAGS_ENV = "DEAPULL_FORM_CFLAGS"
#: seconds a process waits for a form that another process is compiling into the shared cache (dolfinx's
#: default of 10 s is shorter than one -O3 compile of the Jacobian beside another: on a fresh cache the
#: sweep's second rank, solving its own setup on COMM_SELF, then fails with a TimeoutError)
JIT_TIMEOUT_S = 900


def form(expr):
    flags = os.environ.get(FORM_CFLAGS_ENV, FORM_CFLAGS).split()
    return dolfinx.fem.form(expr, jit_params={"cffi_extra_compile_args": flags, "timeout": JIT_TIMEOUT_S})


def create_vector(compiled):
    return dolfinx.fem.petsc.create_vector(compiled)


def create_matrix(compiled):
    return dolfinx.fem.petsc.create_matrix(compiled)


def assemble_residual(b, compiled_F, compiled_J, bcs, x, lifting=True, rows=()):
    """b = F(x), with the Dirichlet rows set to x − g so that the Newton update enforces g.

    ``lifting=False`` skips the lifting of the Jacobian's bc columns: exact when every bc is
    homogeneous and the state already satisfies it (the clamp), and it saves an element-
    matrix pass over the cells next to the bcs in every residual evaluation. Returns, for each
    array of owned ``rows``, the local sum of F over them before the Dirichlet rows are set
    (without lifting: the reactions there, to be summed over ranks).
    """
    with b.localForm() as loc:
        loc.set(0.0)
    dolfinx.fem.petsc.assemble_vector(b, compiled_F)
    if lifting:
        dolfinx.fem.petsc.apply_lifting(b, [compiled_J], bcs=[bcs], x0=[x], scale=-1.0)
    b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    sums = [float(b.array_r[r].sum()) for r in rows]
    dolfinx.fem.petsc.set_bc(b, bcs, x, -1.0)
    return sums


def assemble_vector_free(b, compiled_F):
    """b = F(x) on every row, the Dirichlet rows included (their entries are the reactions);
    owned entries complete (ghost contributions added)."""
    with b.localForm() as loc:
        loc.set(0.0)
    dolfinx.fem.petsc.assemble_vector(b, compiled_F)
    b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)


def owned_component_dofs(space, mesh, facets, component: int, mixed: bool) -> np.ndarray:
    """Indices, in the owned part of the space's PETSc vector, of the displacement's
    ``component`` dofs on the given facets (the displacement is sub-space 0 when ``mixed``)."""
    sub = space.sub(0).sub(component) if mixed else space.sub(component)
    collapsed, _ = sub.collapse()
    dofs = dolfinx.fem.locate_dofs_topological((sub, collapsed), mesh.topology.dim - 1, facets)[0]
    owned = space.dofmap.index_map.size_local * space.dofmap.index_map_bs
    return np.asarray(dofs[dofs < owned], dtype=np.int32)


def assemble_jacobian(A, compiled_J, bcs):
    A.zeroEntries()
    dolfinx.fem.petsc.assemble_matrix(A, compiled_J, bcs=bcs)
    A.assemble()


def assemble_scalar(compiled, comm):
    return comm.allreduce(dolfinx.fem.assemble_scalar(compiled), op=MPI.SUM)


class ScalarBatch:
    """Several scalar integrals (``ufl.Form``s, each on any measure) assembled in one pass: the
    vector form Σ_i f_i v_i over a DG0 vector space with one component per integral, whose
    entries summed per component are the integrals. The kernel evaluates what the integrands
    share (the contact gap and normal) once per quadrature point, not once per integral."""

    def __init__(self, forms, mesh):
        self.k = len(forms)
        space = function_space(mesh, element("DG", mesh, 0, shape=(self.k,)))
        v = ufl.TestFunction(space)
        total = 0
        for i, f in enumerate(forms):
            for itg in f.integrals():
                measure = ufl.Measure(itg.integral_type(), domain=itg.ufl_domain(), subdomain_id=itg.subdomain_id(),
                                      metadata=itg.metadata(), subdomain_data=itg.subdomain_data())
                total = total + itg.integrand() * v[i] * measure
        self.form = form(total)
        self.b = create_vector(self.form)

    def values(self, comm) -> np.ndarray:
        """The integrals, summed over all ranks (k,)."""
        assemble_vector_free(self.b, self.form)
        return comm.allreduce(self.b.array_r.reshape(-1, self.k).sum(axis=0), op=MPI.SUM)


def facets_with_tag(facet_tags, tag):
    return facet_tags.indices[facet_tags.values == tag]


def integration_measures(mesh, cell_tags, facet_tags, quadrature_degree):
    md = {"quadrature_degree": quadrature_degree}
    dx = ufl.Measure("dx", domain=mesh, subdomain_data=cell_tags, metadata=md)
    ds = ufl.Measure("ds", domain=mesh, subdomain_data=facet_tags, metadata=md)
    return dx, ds


#: scene names of the contact quadrature rules -> FFCx's names
QUADRATURE_RULES = {"gauss": "default", "gauss_lobatto": "GLL"}


def facet_measure(mesh, facet_tags, tag, degree, rule="gauss"):
    """The ds measure of one tagged facet group (or a tuple of tags) with its own quadrature: degree and rule
    (``gauss``: Gauss–Legendre points inside the facet; ``gauss_lobatto``: Gauss–Lobatto–
    Legendre points, which include the facet's edges and corners)."""
    md = {"quadrature_degree": degree, "quadrature_rule": QUADRATURE_RULES[rule]}
    return ufl.Measure("ds", domain=mesh, subdomain_data=facet_tags, subdomain_id=tag, metadata=md)


def dirichlet_zero_component(space, mesh, facets, component: int, mixed: bool):
    """u_component = 0 on the facets (the displacement is sub-space 0 when ``mixed``)."""
    sub = space.sub(0).sub(component) if mixed else space.sub(component)
    collapsed, _ = sub.collapse()
    dofs = dolfinx.fem.locate_dofs_topological((sub, collapsed), mesh.topology.dim - 1, facets)
    return dolfinx.fem.dirichletbc(dolfinx.fem.Function(collapsed), dofs, sub)


def facet_quadrature_points(mesh, facets, degree, rule="gauss"):
    """Physical points (n, 3) of a facet measure's quadrature (:func:`facet_measure`) on
    the given facets, and the cell (n,) each lies in.

    Each facet's rule is placed on its face of the reference cell as the form compiler places it
    (v0 + s (v1 - v0) + t (v2 - v0) over the face's reference vertices) and pushed forward by the
    cell's coordinate map, so the points lie on curved (second-order) facets too, such as the DEA's
    rounded free edge.
    """
    tdim = mesh.topology.dim
    facets = np.asarray(facets, dtype=np.int32)
    mesh.topology.create_connectivity(tdim - 1, tdim)
    mesh.topology.create_connectivity(tdim, tdim - 1)
    f2c = mesh.topology.connectivity(tdim - 1, tdim)
    c2f = mesh.topology.connectivity(tdim, tdim - 1)
    quad = mesh.topology.cell_type == dolfinx.mesh.CellType.hexahedron
    cell_type = basix.CellType.hexahedron if quad else basix.CellType.tetrahedron
    facet_type = basix.CellType.quadrilateral if quad else basix.CellType.triangle
    qtype = basix.quadrature.string_to_type(QUADRATURE_RULES[rule])
    ref, _ = basix.make_quadrature(qtype, facet_type, degree)
    s, t = ref[:, :1], ref[:, 1:2]
    vertices, faces = basix.geometry(cell_type), basix.topology(cell_type)[tdim - 1]
    cmap, dofmap, x = mesh.geometry.cmap, mesh.geometry.dofmap, mesh.geometry.x
    points, cells = [np.zeros((0, 3))], []
    for f in facets:
        c = f2c.links(f)[0]
        v = vertices[faces[list(c2f.links(c)).index(f)]]
        X = v[0] + s * (v[1] - v[0]) + t * (v[2] - v[0])
        points.append(cmap.push_forward(X, x[dofmap.links(c)]))
        cells.append(np.full(len(X), c, dtype=np.int32))
    return np.concatenate(points), (np.concatenate(cells) if cells else np.zeros(0, dtype=np.int32))


class PointEvaluator:
    """Values of a vector field at fixed points, as one sparse product.

    ``Function.eval`` pulls every point back to its cell (a Newton solve per point on
    non-affine hexahedra) each time it is called (docs/fem_accuracy.md has its cost on the
    coin scenes). The points here do not move in the reference configuration,
    so they are pulled back once, the element's basis is tabulated there once, and
    :meth:`values` is ``B @ w.x.array`` (row 3 p + i = component i at point p).

    ``function`` is the whole state; ``subspace`` picks the vector field inside a mixed space
    (None: ``function`` is the vector field). Built for Lagrange elements whose cell dofs need
    no transformations (degree ≤ 2 on hexahedra); anything else falls back to
    ``Function.eval``. Checked against ``Function.eval`` on a random field when built, and
    refused loudly if it disagrees.
    """

    def __init__(self, function, points, cells, subspace=None):
        self.subspace = subspace
        self.points, self.cells = np.asarray(points, dtype=float), np.asarray(cells, dtype=np.int32)
        self.B = None
        space = function.function_space if subspace is None else function.function_space.sub(subspace)
        mesh = space.mesh
        n, gdim = self.points.shape[0], mesh.geometry.dim
        comps = [space.sub(i) for i in range(gdim)]
        # the check's probe, made on every rank before any returns: making a Function is collective
        # (a rank without points, e.g. the clamp's half of a split mesh, would leave the others waiting)
        probe = dolfinx.fem.Function(function.function_space)
        if n == 0 or any(c.element.needs_dof_transformations for c in comps):
            return
        cell = {"hexahedron": basix.CellType.hexahedron, "tetrahedron": basix.CellType.tetrahedron}[
            mesh.ufl_cell().cellname()]
        basis = basix.create_element(basix.ElementFamily.P, cell, comps[0].ufl_element().degree(),
                                     basix.LagrangeVariant.gll_warped)
        ref = np.empty_like(self.points)
        gx, gmap, cmap = mesh.geometry.x, mesh.geometry.dofmap, mesh.geometry.cmap
        for c in np.unique(self.cells):
            at = self.cells == c
            ref[at] = cmap.pull_back(self.points[at], gx[gmap.links(c), :gdim])
        phi = basis.tabulate(0, ref)[0, :, :, 0]                       # (n, dofs per cell)
        rows, cols = [], []
        for i, comp in enumerate(comps):
            rows.append(np.repeat(gdim * np.arange(n) + i, phi.shape[1]))
            cols.append(np.array([comp.dofmap.list.links(c) for c in self.cells]).ravel())
        self.B = scipy.sparse.csr_matrix((np.tile(phi.ravel(), gdim), (np.concatenate(rows), np.concatenate(cols))),
                                         shape=(gdim * n, len(function.x.array)))
        self._check(probe)

    def _field(self, function):
        return function if self.subspace is None else function.sub(self.subspace)

    def _check(self, probe):
        probe.x.array[:] = np.random.default_rng(0).standard_normal(len(probe.x.array))
        expected = self._field(probe).eval(self.points, self.cells)
        got = (self.B @ probe.x.array).reshape(expected.shape)
        err = float(np.max(np.abs(got - expected))) / float(np.max(np.abs(expected)))
        if not err < 1e-10:
            raise RuntimeError(f"PointEvaluator disagrees with Function.eval by {err:.3g} (relative): the element's "
                               "dof layout is not the one it assumes (fem_solver/compat.py)")

    def values(self, function) -> np.ndarray:
        """(n, 3) values of the field at the points (``function``: the whole state, as built)."""
        if not len(self.points):
            return np.zeros((0, 3))
        if self.B is None:
            return self._field(function).eval(self.points, self.cells)
        return (self.B @ function.x.array).reshape(len(self.points), -1)


def num_cells_global(mesh) -> int:
    imap = mesh.topology.index_map(mesh.topology.dim)
    return imap.size_global


def xdmf_writer(comm, path, mesh):
    f = dolfinx.io.XDMFFile(comm, str(path), "w")
    f.write_mesh(mesh)
    return f


def interpolate_to_p1(u, mesh):
    """Interpolate a (P2) vector field onto the mesh's own geometry space, for XDMF output."""
    V1 = dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", cell_degree(mesh)))
    out = dolfinx.fem.Function(V1, name=u.name)
    out.interpolate(u)
    return out


