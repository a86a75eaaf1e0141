"""Where the DEA touches the coin and the table: the section at the symmetry plane z = 0 and the
contact patch, from the solver's field output.

The run's dataset records per step the number of the coin's active contact points
(``n_contact``) and the traction-weighted contact centre (``contact_x``, ``contact_z``, and
``contact_abs_z``, how far from the mid-plane the patches sit), not
the traction at each point. This module recomputes it as ``fem_solver/contact.py`` defines it:
the DEA's deformed underside is sampled at the contact integral's own quadrature points (the
scene's ``contact.quadrature_rule`` and ``quadrature_degree`` on each underside face of the
modelled mesh, the face's nodes interpolated with its Lagrange shape functions); the depth of a
point in the coin (an upright cylinder with a rounded top rim, moved by the coin's x(t)) is
δ = −d, d the signed distance, and its normal traction p_n = k_n δ with
k_n = ``contact.penalty_N_m3``. On the table (``[table]``: the plane y = ``table.height_m``,
its own Gauss–Lobatto rule) δ = height − y and k = ``table.penalty_N_m3``. A point touches
when δ > 0; the picture prints its count of the coin's points beside the solver's
``n_contact`` at the same time as a check. Hexahedral meshes are sampled at the quadrature
points; other meshes at the underside's nodes.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from deapull import scene as scenes
from deapull.errors import InputError
from deapull.geometry import rounded_cylinder_distance
from deapull.workflows.report.pictures import (STAGES, CoinGeometry, Colouring, Scene3D, _coin_x_mm, _hex_lattice,
                                               _vtk_lattice,
                                               coin_outline_mm, colouring, draw_table, frame_title, plt, save_png)
from matplotlib.collections import PolyCollection  # noqa: E402  (after pictures chose the Agg backend)
from matplotlib.patches import Circle, Polygon  # noqa: E402

#: colour map of the contact pressure (apart from the displacement's viridis)
PRESSURE_CMAP = "autumn_r"


def coin_depth(x: np.ndarray, coin: CoinGeometry, x_shift_m: float) -> np.ndarray:
    """Penetration δ (m, > 0 inside) of points ``x`` (n, 3) into the coin moved by ``x_shift_m``."""
    rho = np.hypot(x[:, 0] - coin.centre_x_m - x_shift_m, x[:, 2])
    return -rounded_cylinder_distance(rho, x[:, 1], coin.height_m, coin.radius_m, coin.edge_radius_m, coin.edge_shape)


@dataclass(frozen=True)
class Touch:
    """The sample points that touch one body: their current positions (m) and normal traction (Pa)."""
    points: np.ndarray          # (k, 3)
    pressure: np.ndarray        # (k,)

    @property
    def n(self) -> int:
        return len(self.pressure)


def touching(x: np.ndarray, depth: np.ndarray, penalty_N_m3: float) -> Touch:
    """The points of positive depth, with the penalty traction p = k δ."""
    on = depth > 0.0
    return Touch(x[on], penalty_N_m3 * depth[on])


def rule_points(degree: int, rule: str) -> np.ndarray:
    """1D points on [0, 1] of basix's rule of that degree per direction of a quadrilateral:
    Gauss (degree // 2 + 1 points) or Gauss–Lobatto (degree // 2 + 2, the ends included)."""
    if rule == "gauss_lobatto":
        m = degree // 2 + 2
        inner = np.polynomial.legendre.Legendre.basis(m - 1).deriv().roots()
        ref = np.concatenate([[-1.0], np.real(inner), [1.0]])
    else:
        ref = np.polynomial.legendre.leggauss(degree // 2 + 1)[0]
    return np.sort((ref + 1.0) / 2.0)


def _lagrange(q: np.ndarray, n: int) -> np.ndarray:
    """(len(q), n) values of the 1D Lagrange basis on n equally spaced nodes of [0, 1]."""
    nodes = np.linspace(0.0, 1.0, n)
    L = np.ones((len(q), n))
    for j in range(n):
        for k in range(n):
            if k != j:
                L[:, j] *= (q - nodes[k]) / (nodes[j] - nodes[k])
    return L


def underside_faces(s: Scene3D, y_m: float) -> np.ndarray:
    """(f, n, n) node ids of the hexahedra's faces on the plane y = ``y_m`` of the reference mesh
    (indexed by x, then z); empty for other cells."""
    f = s.fields
    if not f.cell_type.lower().startswith("hexahedron"):
        return np.zeros((0, 1, 1), dtype=np.int64)
    n = {8: 2, 27: 3}[f.cells.shape[1]]
    tol = 1e-9 * float(np.ptp(f.points[:, 1]) or 1.0)
    faces = []
    for c in f.cells:
        try:
            faces.append(_hex_lattice(f.points, c, n)[:, 0, :])
        except InputError:      # a curved cell (the rounded free edge): not a flat underside face
            continue
    return np.array([g for g in faces if np.all(np.abs(f.points[g, 1] - y_m) <= tol)], dtype=np.int64).reshape(
        -1, n, n)


def underside_samples(s: Scene3D, frame: int, degree: int, rule: str) -> np.ndarray:
    """Current positions (m) of the quadrature points on the DEA's underside in the modelled
    mesh (the underside's nodes when it has no hexahedral faces)."""
    y0 = scenes.layout_bottom(s.scene)
    x = s.fields.points + s.fields.displacement(frame)
    faces = underside_faces(s, y0)
    if not len(faces):
        return x[np.isclose(s.fields.points[:, 1], y0)]
    L = _lagrange(rule_points(degree, rule), faces.shape[1])
    return np.einsum("ai,bj,fijd->fabd", L, L, x[faces]).reshape(-1, 3)


def coin_contact(s: Scene3D, frame: int) -> Touch:
    """The coin's active contact points of a frame and their pressure p_n (modelled mesh)."""
    c = s.scene.contact
    x = underside_samples(s, frame, c.quadrature_degree, c.quadrature_rule)
    return touching(x, coin_depth(x, s.coin, s.at(s.run_x, frame)), c.penalty_N_m3)


def table_contact(s: Scene3D, frame: int) -> Touch | None:
    """The table's active contact points of a frame (None without a [table])."""
    tb = s.scene.table
    if tb is None:
        return None
    x = underside_samples(s, frame, tb.quadrature_degree, "gauss_lobatto")
    return touching(x, tb.height_m - x[:, 1], tb.penalty_N_m3)


def plane_faces(s: Scene3D, z_m: float = 0.0) -> np.ndarray:
    """Quads (node ids) of the hexahedra's faces on the plane z = ``z_m``: the section there
    (for a half model, the symmetry plane itself)."""
    f = s.fields
    n = {8: 2, 27: 3}.get(f.cells.shape[1])
    if not f.cell_type.lower().startswith("hexahedron") or n is None:
        return np.zeros((0, 4), dtype=np.int64)
    tol = 1e-9 * float(np.ptp(f.points[:, 2]) or 1.0)
    seen, quads = set(), []
    for cell in f.cells:
        try:
            g = _hex_lattice(f.points, cell, n)
        except InputError:         # a curved cell (the rounded free edge's O-grid): its VTK node order
            g = _vtk_lattice(cell, n)
        for face in (g[0], g[-1], g[:, 0], g[:, -1], g[:, :, 0], g[:, :, -1]):
            key = frozenset(face.ravel().tolist())
            if key in seen or not np.all(np.abs(f.points[face, 2] - z_m) <= tol):
                continue
            seen.add(key)
            quads += [(face[a, b], face[a + 1, b], face[a + 1, b + 1], face[a, b + 1]) for a in range(n - 1)
                      for b in range(n - 1)]
    return np.array(quads, dtype=np.int64).reshape(-1, 4)


def _mirrored(s: Scene3D, touch: Touch) -> Touch:
    """A half model's points with their mirror images (z → −z), for drawing."""
    if not s.mirrored:
        return touch
    return Touch(np.vstack([touch.points, touch.points * [1.0, 1.0, -1.0]]), np.tile(touch.pressure, 2))


def draw_section(ax, s: Scene3D, frame: int, colour: Colouring, coin: Touch, pmax: float):
    """The section at z = 0: table, coin, DEA (coloured by ``colour``) and, over them, the coin's
    active contact points projected on the plane (they lie on the coin's top face or rim),
    coloured by pressure; returns the DEA's collection. The table's points lie beside the coin
    (|z| > radius) and are left to the plan view: projected they would fall on the coin."""
    X = (s.fields.points + s.fields.displacement(frame)) * 1e3
    quads = plane_faces(s)
    lo, hi = s.points.min(0) * 1e3, s.points.max(0) * 1e3
    xlim = (lo[0] - 4.0, hi[0] + 2.0)
    draw_table(ax, s, xlim)
    ax.add_patch(Polygon(coin_outline_mm(s.coin, _coin_x_mm(s, frame) * 1e-3), facecolor=(0.62, 0.62, 0.67),
                         edgecolor="0.25", zorder=2))
    coll = PolyCollection(X[quads][:, :, :2], cmap="viridis", edgecolors=(0, 0, 0, 0.3), linewidths=0.3, zorder=3)
    coll.set_array(colour.node_mm[quads].mean(axis=1))
    coll.set_clim(0.0, colour.vmax_mm)
    ax.add_collection(coll)
    ax.scatter(coin.points[:, 0] * 1e3, coin.points[:, 1] * 1e3, c=coin.pressure / 1e3, s=22, cmap=PRESSURE_CMAP,
               vmin=0.0, vmax=pmax, edgecolors="k", linewidths=0.5, zorder=5)
    ax.axvline(hi[0], color="0.2", lw=3.0)
    ax.set_xlim(*xlim)
    ax.set_ylim(min(-0.5, (s.table_height_m or 0.0) * 1e3 - 1.0), hi[1] + 2.0)
    ax.set_aspect("equal")
    ax.set_xlabel("x [mm] (clamp at x = 0)")
    ax.set_ylabel("y [mm]")
    return coll


def draw_patch(ax, s: Scene3D, frame: int, coin: Touch, table: Touch | None, pmax: float):
    """Plan view (x–z, from above) of the contact patches near the tip: the coin's outline, the
    DEA's underside sample points in grey, the active ones coloured by pressure (circles on the
    coin, squares on the table), the solver's contact centre; returns the pressure scatter."""
    c = s.coin
    xc = (c.centre_x_m + s.at(s.run_x, frame)) * 1e3
    under = underside_samples(s, frame, s.scene.contact.quadrature_degree, s.scene.contact.quadrature_rule)
    under = _mirrored(s, Touch(under, np.zeros(len(under)))).points * 1e3
    ax.scatter(under[:, 0], under[:, 2], s=2, color="0.75", zorder=1)
    ax.add_patch(Circle((xc, 0.0), c.radius_m * 1e3, fill=False, color="0.3", lw=1.2, zorder=2))
    ax.add_patch(Circle((xc, 0.0), (c.radius_m - c.edge_radius_m) * 1e3, fill=False, color="0.5", lw=0.6, ls=":",
                        zorder=2))
    sc = None
    for touch, marker in ((table, "s"), (coin, "o")):
        if touch is not None:
            shown = _mirrored(s, touch)
            sc = ax.scatter(shown.points[:, 0] * 1e3, shown.points[:, 2] * 1e3, c=shown.pressure / 1e3, s=30,
                            marker=marker, cmap=PRESSURE_CMAP, vmin=0.0, vmax=pmax, edgecolors="k", linewidths=0.5,
                            zorder=4)
    if "contact_x" in s.run:
        cx = s.at("contact_x", frame) * 1e3
        if "contact_abs_z" in s.run and s.at("contact_abs_z", frame) > 0:   # one cross per patch, at ±|z|
            cz = s.at("contact_abs_z", frame) * 1e3
            ax.plot([cx, cx], [cz, -cz], "x", color="b", ms=9, mew=2, zorder=5,
                    label="solver's contact centre of each patch (contact_x, ±contact_abs_z)")
        else:
            ax.plot([cx], [s.at("contact_z", frame) * 1e3 if "contact_z" in s.run else 0.0],
                    "x", color="b", ms=9, mew=2, zorder=5, label="solver's contact centre")
        ax.legend(loc="upper center", fontsize=7, bbox_to_anchor=(0.5, -0.12))
    r, half = c.radius_m * 1e3 + 2.0, s.points[:, 2].max() * 1e3 + 1.0
    ax.set_xlim(xc - r, xc + r)
    ax.set_ylim(-half, half)
    ax.set_aspect("equal")
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("z [mm]")
    return sc


def contact_summary(s: Scene3D, frame: int, coin: Touch, table: Touch | None) -> str:
    """One line: the coin's active points (the solver's count beside), peak pressure, the table's."""
    solver = f" (solver: {s.at('n_contact', frame):.0f})" if "n_contact" in s.run else ""
    peak = f", peak p_n = {coin.pressure.max() / 1e3:.3g} kPa" if coin.n else ""
    half = " in the modelled half" if s.mirrored else ""
    text = f"coin: {coin.n} active points{half}{solver}{peak}"
    if table is not None:
        text += f"; table: {table.n} active points"
    return text


def section_picture(s: Scene3D, stage: str, frame: int, png: Path, dpi: int = 100) -> Path:
    """The section at z = 0 (left) and the coin's contact patch from above (right) of one frame,
    into ``png`` (atomic)."""
    coin = coin_contact(s, frame)
    table = table_contact(s, frame)
    pressures = [t.pressure for t in (coin, table) if t is not None and t.n]
    pmax = max(float(np.concatenate(pressures).max()) / 1e3 if pressures else 0.0, 1e-9)
    colour = colouring(s, frame)
    fig = plt.figure(figsize=(12, 4.6))
    ax = fig.add_axes((0.05, 0.18, 0.5, 0.62))
    coll = draw_section(ax, s, frame, colour, coin, pmax)
    ax.set_title("section at the symmetry plane z = 0 (the coin's contact points projected on it)", fontsize=9)
    fig.colorbar(coll, cax=fig.add_axes((0.565, 0.2, 0.008, 0.55)), label=colour.label)
    ax = fig.add_axes((0.66, 0.14, 0.26, 0.74))
    sc = draw_patch(ax, s, frame, coin, table, pmax)
    ax.set_title("contact, from above (○ coin, □ table)", fontsize=9)
    fig.colorbar(sc, cax=fig.add_axes((0.92, 0.2, 0.008, 0.55)), label="contact pressure p_n = k_n δ [kPa]")
    fig.suptitle(f"{s.setup}: {dict(STAGES)[stage]} — {frame_title(s, frame)}\n"
                 f"{contact_summary(s, frame, coin, table)}", fontsize=10, y=1.04)
    save_png(fig, png, dpi)
    return Path(png)
