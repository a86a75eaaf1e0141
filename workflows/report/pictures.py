"""Pictures of the deforming DEA and the coin from the solver's field output (off-screen).

``deapull solve ... --fields-every N`` writes the displacement of the DEA every N accepted
steps as XDMF (``<setup>_fields.xdmf``, the geometry and topology once, one ``Time`` per
frame) with its data in HDF5 (``<setup>_fields.h5``). This module reads both with the
standard library's XML parser and h5py (no dolfinx, no VTK), extracts the boundary faces
of the mesh (hexahedra of 8 or 27 nodes, tetrahedra of 4 or 10) and draws them with
matplotlib. The colour is the actuation |u(t) − u(rest)| (mm), the motion since the first frame
(the DEA settled on the coin under gravity at V = 0), so the gravity sag is left out; the rest
frame itself shows that sag |u(rest)| on its own, labelled scale. The coin is the rigid disc of
the scene (radius, height, rounded rim, centre from the tip), shifted by the coin's x(t) from
the run's dataset (``<setup>.nc`` beside the fields); the table is the plane y =
``table.height_m`` of a scene with a ``[table]``. The side view draws the DEA's polygons behind
the plane z = 0, the coin, then those in front of it, so the DEA passes in front of and behind
the coin as it does in space. A half model (``mesh.symmetry = "half_z"``) is mirrored to the
whole DEA. The section at z = 0 and the contact patch are in :mod:`.pictures_contact`.

Stages (the paper's Fig. 4): *at rest* is the first frame (the DEA settled on the coin
under gravity, V = 0), *static stage* the last frame before the coin starts to slide
(dataset variable ``stick``), *kinetic stage* the last frame. The animation (the side view
beside the coin's x(t) with a marker at the frame's time) is an animated GIF written with
Pillow (matplotlib's own image dependency).
"""
from __future__ import annotations

import io
import logging

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.collections import PolyCollection  # noqa: E402
from matplotlib.patches import Polygon, Rectangle  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402
from PIL import Image  # noqa: E402
from tqdm import tqdm  # noqa: E402

from deapull import dataset, scene as scenes  # noqa: E402
from deapull.errors import InputError  # noqa: E402
from deapull.io import atomic_write  # noqa: E402

log = logging.getLogger(__name__)

#: the paper's three stages: (key, title)
STAGES = (("rest", "at rest (V = 0, settled on the coin)"), ("static", "static stage (coin sticks)"),
          ("kinetic", "kinetic stage (coin slides)"))
#: camera of each view: (title, elevation, azimuth) in matplotlib's 3D axes (plot z = our y, up); the side
#: view is drawn as an exact 2D projection on the x-y plane instead (:func:`draw_side`)
VIEWS = (("side", 0.0, -90.0), ("3/4", 24.0, -58.0))


@dataclass(frozen=True)
class Fields:
    """The displacement frames of one field file."""
    path: Path
    points: np.ndarray          # (n, 3) reference node coordinates (m)
    cells: np.ndarray           # (c, k) node ids per cell
    cell_type: str              # XDMF topology type, e.g. Hexahedron_27
    times: np.ndarray           # (f,) s
    keys: tuple                 # HDF5 dataset path of each frame

    def displacement(self, frame: int) -> np.ndarray:
        with h5py.File(self.path.with_suffix(".h5"), "r") as f:
            return np.asarray(f[self.keys[frame]][:], dtype=float)


def _h5_ref(item: ET.Element, xdmf: Path) -> tuple[Path, str]:
    text = (item.text or "").strip()
    if ":" not in text:
        raise InputError(f"{xdmf}: DataItem {text!r} is not an HDF5 reference (file.h5:/path)")
    name, key = text.split(":", 1)
    return xdmf.parent / name, key


def read_fields(xdmf) -> Fields:
    """Read the mesh and the frame list of an XDMF field file (data stays in HDF5 until needed)."""
    xdmf = Path(xdmf)
    if not xdmf.is_file():
        raise InputError(f"field file {str(xdmf)!r}: not found (make it with `deapull solve ... --fields-every N`)")
    try:
        root = ET.parse(xdmf).getroot()
    except ET.ParseError as err:
        raise InputError(f"field file {xdmf}: not valid XML ({err})") from None
    grids = list(root.iter("Grid"))
    mesh_grid = next((g for g in grids if g.get("GridType") == "Uniform" and g.find("Topology") is not None), None)
    if mesh_grid is None:
        raise InputError(f"field file {xdmf}: no mesh (Topology/Geometry)")
    topo = mesh_grid.find("Topology")
    cell_type = topo.get("TopologyType", "")
    h5, topo_key = _h5_ref(topo.find("DataItem"), xdmf)
    _, geo_key = _h5_ref(mesh_grid.find("Geometry").find("DataItem"), xdmf)
    frames = []
    for g in grids:
        time, attr = g.find("Time"), g.find("Attribute")
        if time is None or attr is None:
            continue
        frames.append((float(time.get("Value")), _h5_ref(attr.find("DataItem"), xdmf)[1]))
    if not frames:
        raise InputError(f"field file {xdmf}: no time frames")
    frames.sort()
    if not h5.is_file():
        raise InputError(f"field file {xdmf}: its data file {h5} is missing")
    with h5py.File(h5, "r") as f:
        points = np.asarray(f[geo_key][:], dtype=float)
        cells = np.asarray(f[topo_key][:], dtype=np.int64)
    return Fields(xdmf, points, cells, cell_type, np.array([t for t, _ in frames]), tuple(k for _, k in frames))


#: lattice positions (x, y, z in {0, .., n-1}) of the nodes of VTK's hexahedra, the order of the XDMF
#: that dolfinx writes: 8 corners, then (27 nodes) 12 edge midpoints, 6 face centres and the centre
_VTK_HEX = {
    8: ((0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)),
    27: ((0, 0, 0), (2, 0, 0), (2, 2, 0), (0, 2, 0), (0, 0, 2), (2, 0, 2), (2, 2, 2), (0, 2, 2),
         (1, 0, 0), (2, 1, 0), (1, 2, 0), (0, 1, 0), (1, 0, 2), (2, 1, 2), (1, 2, 2), (0, 1, 2),
         (0, 0, 1), (2, 0, 1), (2, 2, 1), (0, 2, 1),
         (0, 1, 1), (2, 1, 1), (1, 0, 1), (1, 2, 1), (1, 1, 0), (1, 1, 2), (1, 1, 1)),
}


def _hex_lattice(points: np.ndarray, cell: np.ndarray, n: int) -> np.ndarray:
    """(n, n, n) array of the cell's node ids by position in its (axis-aligned) reference box,
    indexed by x, y, z."""
    X = points[cell]
    lo, hi = X.min(0), X.max(0)
    idx = np.rint((X - lo) / np.where(hi > lo, hi - lo, 1.0) * (n - 1)).astype(int)
    grid = -np.ones((n, n, n), dtype=np.int64)
    grid[idx[:, 0], idx[:, 1], idx[:, 2]] = cell
    if (grid < 0).any():
        raise InputError("field mesh: a hexahedron is not an axis-aligned box in the reference configuration; "
                         "cannot place its nodes")
    return grid


def _vtk_lattice(cell: np.ndarray, n: int) -> np.ndarray:
    """(n, n, n) array of the cell's node ids by their place in its reference cube, from VTK's node
    order (the XDMF that dolfinx writes): the faces of any hexahedron, curved ones too (the rounded
    free edge's O-grid), in the cell's own axes."""
    idx = np.array(_VTK_HEX[len(cell)])
    grid = np.empty((n, n, n), dtype=np.int64)
    grid[idx[:, 0], idx[:, 1], idx[:, 2]] = cell
    return grid


def boundary_faces(points: np.ndarray, cells: np.ndarray, cell_type: str) -> list[tuple]:
    """Polygons (tuples of node ids) covering the mesh boundary: quads for hexahedra (each
    9-node face split in 4), triangles for tetrahedra (their vertices)."""
    count: dict[frozenset, list] = {}     # face -> its polygons, once per cell that has it
    kind = cell_type.lower()
    for cell in cells:
        if kind.startswith("hexahedron"):
            n = {8: 2, 27: 3}.get(len(cell))
            if n is None:
                raise InputError(f"field mesh: hexahedra of {len(cell)} nodes are not supported (8 or 27)")
            try:
                g = _hex_lattice(points, cell, n)
            except InputError:     # a curved cell (the rounded free edge's O-grid): its VTK node order
                g = _vtk_lattice(cell, n)
            faces = [g[0], g[-1], g[:, 0], g[:, -1], g[:, :, 0], g[:, :, -1]]
            for f in faces:
                quads = [(f[a, b], f[a + 1, b], f[a + 1, b + 1], f[a, b + 1]) for a in range(n - 1)
                         for b in range(n - 1)]
                count.setdefault(frozenset((f[0, 0], f[0, -1], f[-1, 0], f[-1, -1])), []).append(quads)
        elif kind.startswith("tetrahedron"):
            v = cell[:4]
            for tri in ((v[0], v[1], v[2]), (v[0], v[1], v[3]), (v[0], v[2], v[3]), (v[1], v[2], v[3])):
                count.setdefault(frozenset(tri), []).append([tri])
        else:
            raise InputError(f"field mesh: cell type {cell_type!r} is not supported (hexahedra, tetrahedra)")
    # a face of one cell only is on the boundary
    return [poly for seen in count.values() if len(seen) == 1 for poly in seen[0]]


@dataclass(frozen=True)
class CoinGeometry:
    centre_x_m: float           # at rest (x = 0)
    radius_m: float
    height_m: float
    edge_radius_m: float = 0.0  # fillet of the top rim
    edge_shape: str = "circular"  # its profile (deapull.geometry)


def run_scene(run_attrs: dict):
    """The run's resolved scene (from the dataset's ``scene_toml``), None when it has none."""
    text = run_attrs.get("scene_toml", "")
    return scenes.from_resolved_toml(text) if text else None


def coin_geometry(sc) -> CoinGeometry | None:
    """The coin of a scene, None without a coin (or scene)."""
    if sc is None or sc.coin is None:
        return None
    return CoinGeometry(-sc.dea.length_m + sc.coin.center_from_tip_m, sc.coin.radius_m, sc.coin.height_m,
                        sc.coin.edge_radius_m, sc.coin.edge_shape)


def mirror_z(points: np.ndarray, polys: list) -> tuple[np.ndarray, list]:
    """A half model (z >= 0, mesh.symmetry = half_z) made whole: the nodes mirrored to -z
    (ids + n), the boundary polygons doubled, those on the symmetry plane dropped."""
    n = len(points)
    scale = float(np.ptp(points[:, 2])) or 1.0
    on_plane = np.abs(points[:, 2]) <= 1e-9 * scale
    kept = [p for p in polys if not on_plane[list(p)].all()]
    return np.vstack([points, points * [1.0, 1.0, -1.0]]), kept + [tuple(i + n for i in p[::-1]) for p in kept]


#: the run's columns a picture reads when its dataset has them (the solver's contact record)
RUN_OPTIONAL = ("stick", "n_contact", "contact_x", "contact_z", "contact_abs_z", "table_penetration_m")
#: the colour bars of the two colourings
ACTUATION_LABEL = "actuation |u(t) − u(rest)| [mm]\n(from the settled rest state: the sag left out)"
SAG_LABEL = "gravity sag |u(rest)| [mm]\n(the rest state: the reference of the other frames)"
#: the moving marker of the animation's x(t) panel
MARKER = (0.85, 0.05, 0.05)


@dataclass(frozen=True)
class Scene3D:
    """Everything a picture needs: the field frames, boundary polygons, the run (x, stick) and its scene."""
    fields: Fields
    polys: np.ndarray           # (p, k) node ids
    coin: CoinGeometry | None
    run_t: np.ndarray
    run_x: np.ndarray
    run_V: np.ndarray
    stick: np.ndarray | None
    setup: str
    umax_mm: float              # largest actuation |u - u(rest)| over a sample of frames (mm)
    points: np.ndarray          # reference node coordinates drawn (m): the mesh's, mirrored for a half model
    mirrored: bool = False
    sag_mm: float = 0.0         # largest gravity sag |u(rest)| (mm)
    scene: object = None        # the run's resolved scene, None when its dataset has none
    run: dict = field(default_factory=dict)   # the columns of RUN_OPTIONAL the dataset has

    def displacement(self, frame: int) -> np.ndarray:
        """Nodal displacement (m) of a frame, on :attr:`points`."""
        u = self.fields.displacement(frame)
        return np.vstack([u, u * [1.0, 1.0, -1.0]]) if self.mirrored else u

    def at(self, column, frame: int) -> float:
        """A run column (an array, or the name of one in :attr:`run`) at the frame's time."""
        values = self.run[column] if isinstance(column, str) else column
        return float(np.interp(self.fields.times[frame], self.run_t, values))

    @property
    def table_height_m(self) -> float | None:
        """y of the table's plane, None when the scene has no [table]."""
        table = getattr(self.scene, "table", None)
        return None if table is None else float(table.height_m)


def load_scene3d(xdmf, run_path=None) -> Scene3D:
    """Fields + their run's dataset (default: ``<setup>.nc`` beside ``<setup>_fields.xdmf``)."""
    fields = read_fields(xdmf)
    xdmf = Path(xdmf)
    if run_path is None:
        run_path = xdmf.with_name(xdmf.name.replace("_fields.xdmf", ".nc"))
    run = dataset.read(run_path, variables=("t", "x", "V"), optional=RUN_OPTIONAL)
    polys = boundary_faces(fields.points, fields.cells, fields.cell_type)
    sc = run_scene(run.attrs)
    mirrored = sc is not None and getattr(sc.mesh, "symmetry", "none") == "half_z"
    points = fields.points
    if mirrored:
        points, polys = mirror_z(points, polys)
    rest = fields.displacement(0)
    umax = max(float(np.linalg.norm(fields.displacement(i) - rest, axis=1).max()) for i in
               np.unique(np.linspace(0, len(fields.times) - 1, 12).astype(int)))
    sag = float(np.linalg.norm(rest, axis=1).max())
    extra = {k: run.columns[k] for k in RUN_OPTIONAL if k in run.columns}
    return Scene3D(fields, np.array(polys, dtype=np.int64), coin_geometry(sc), run.columns["t"], run.columns["x"],
                   run.columns["V"], run.columns.get("stick"), str(run.attrs.get("setup", "")), umax * 1e3, points,
                   mirrored, sag * 1e3, sc, extra)


def stage_frames(s: Scene3D) -> dict[str, int]:
    """Frame index of each stage: first frame, last one before sliding starts, last frame."""
    times = s.fields.times
    last = len(times) - 1
    static = last // 2
    if s.stick is not None and (s.stick == 0).any():
        t_slip = s.run_t[int(np.argmax(s.stick == 0))]
        before = np.flatnonzero(times < t_slip)
        static = int(before[-1]) if before.size else 0
    return {"rest": 0, "static": static, "kinetic": last}


@dataclass(frozen=True)
class Colouring:
    """Per-node values (mm) of one frame, the top of the colour range and the colour bar's label."""
    node_mm: np.ndarray
    vmax_mm: float
    label: str

    def of(self, polys: np.ndarray) -> np.ndarray:
        """The mean over each polygon's nodes."""
        return self.node_mm[polys].mean(axis=1)


def actuation(s: Scene3D, frame: int) -> np.ndarray:
    """|u(t) − u(rest)| per node (m): the motion since frame 0 (settled on the coin under
    gravity at V = 0), the gravity sag left out."""
    return np.linalg.norm(s.displacement(frame) - s.displacement(0), axis=1)


def colouring(s: Scene3D, frame: int, sag_at_rest: bool = True) -> Colouring:
    """The actuation of a frame on the run's common scale; frame 0 (where it is zero) shows the
    gravity sag |u(rest)| on its own scale instead when ``sag_at_rest``."""
    if frame == 0 and sag_at_rest:
        return Colouring(np.linalg.norm(s.displacement(0), axis=1) * 1e3, max(s.sag_mm, 1e-9), SAG_LABEL)
    return Colouring(actuation(s, frame) * 1e3, max(s.umax_mm, 1e-9), ACTUATION_LABEL)


def _coin_polys(c: CoinGeometry, x_shift: float, n: int = 36) -> list[np.ndarray]:
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    ring = np.stack([c.centre_x_m + x_shift + c.radius_m * np.cos(a), c.radius_m * np.sin(a)], axis=1) * 1e3
    bottom = np.column_stack([ring[:, 0], ring[:, 1], np.zeros(n)])
    top = np.column_stack([ring[:, 0], ring[:, 1], np.full(n, c.height_m * 1e3)])
    sides = [np.array([bottom[i], bottom[(i + 1) % n], top[(i + 1) % n], top[i]]) for i in range(n)]
    return [bottom, top, *sides]


def coin_outline_mm(c: CoinGeometry, x_shift_m: float, n: int = 8) -> np.ndarray:
    """The coin's side silhouette, which is also its section at z = 0 (mm): a rectangle whose top
    corners are rounded by the rim's fillet."""
    r, h, e, xc = c.radius_m, c.height_m, c.edge_radius_m, c.centre_x_m + x_shift_m
    a = np.linspace(0.0, np.pi / 2, n)
    power = 2.0 / 3.0 if c.edge_shape == "c2" else 1.0     # the superellipse |q|_3 = e, or the circle
    cos, sin = np.cos(a) ** power, np.sin(a) ** power
    right = np.column_stack([xc + r - e + e * cos, h - e + e * sin])
    left = np.column_stack([xc - r + e - e * sin, h - e + e * cos])
    return np.vstack([[xc - r, 0.0], [xc + r, 0.0], right, left]) * 1e3


def draw(ax, s: Scene3D, frame: int, elev: float, azim: float, cmap="viridis", colour: Colouring | None = None,
         alpha: float = 0.6):
    """Draw one frame on a 3D axes, the DEA see-through (``alpha``) so that the coin below shows;
    returns the polygon collection (for a colour bar)."""
    colour = colour or colouring(s, frame)
    P = (s.points + s.displacement(frame)) * 1e3
    P = P[:, [0, 2, 1]]                      # plot (x, z, y): y is up
    if s.coin is not None:
        ax.add_collection3d(Poly3DCollection(_coin_polys(s.coin, _coin_x_mm(s, frame) * 1e-3),
                                             facecolors=(0.55, 0.55, 0.6, 1.0), edgecolors=(0.3, 0.3, 0.3, 0.3),
                                             linewidths=0.2))
    coll = Poly3DCollection(P[s.polys], cmap=cmap, edgecolors=(0, 0, 0, 0.15), linewidths=0.2, alpha=alpha)
    coll.set_array(colour.of(s.polys))
    coll.set_clim(0.0, colour.vmax_mm)
    ax.add_collection3d(coll)
    lo, hi = s.points.min(0) * 1e3, s.points.max(0) * 1e3
    pad = 3.0
    xl, zl, yl = (lo[0] - pad, hi[0] + pad), (lo[2] - pad, hi[2] + pad), (0.0, hi[1] + pad)
    ax.set_xlim(*xl)
    ax.set_ylim(*zl)
    ax.set_zlim(*yl)
    ax.set_box_aspect((xl[1] - xl[0], zl[1] - zl[0], yl[1] - yl[0]))
    ax.set_proj_type("ortho")
    ax.view_init(elev=elev, azim=azim)
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("z [mm]")
    ax.set_zlabel("y [mm]")
    return coll


def draw_table(ax, s: Scene3D, x_range: tuple) -> None:
    """The table as a hatched band below its plane y = table.height_m (the ground line y = 0
    without a [table])."""
    h = s.table_height_m
    if h is None:
        ax.axhline(0.0, color="0.4", lw=1.0, zorder=1)
        return
    ax.add_patch(Rectangle((x_range[0], h * 1e3 - 1.0), x_range[1] - x_range[0], 1.0, facecolor=(0.87, 0.8, 0.68),
                           edgecolor=(0.45, 0.35, 0.2), hatch="//", lw=0.8, zorder=1))
    ax.text(x_range[0] + 0.5, h * 1e3 - 0.5, "table", fontsize=7, va="center", zorder=1)


def side_layers(P: np.ndarray, polys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Polygon indices behind the plane z = 0 (seen from −z) and in front of it, far ones first.
    The coin's axis lies in that plane and the DEA stays outside the coin, so drawing the first
    group, the coin, then the second puts every polygon on its side of the coin."""
    z = P[polys][:, :, 2].mean(axis=1)
    order = np.argsort(-z, kind="stable")
    return order[z[order] >= 0.0], order[z[order] < 0.0]


def draw_side(ax, s: Scene3D, frame: int, cmap="viridis", colour: Colouring | None = None):
    """Side view: the boundary polygons projected on the x-y plane in depth order around the
    coin (:func:`side_layers`), on the table."""
    colour = colour or colouring(s, frame)
    P = (s.points + s.displacement(frame)) * 1e3
    values = colour.of(s.polys)
    lo, hi = s.points.min(0) * 1e3, s.points.max(0) * 1e3
    xlim = (lo[0] - 4.0, hi[0] + 2.0)
    draw_table(ax, s, xlim)
    if s.coin is not None:
        ax.add_patch(Polygon(coin_outline_mm(s.coin, _coin_x_mm(s, frame) * 1e-3), facecolor=(0.62, 0.62, 0.67),
                             edgecolor="0.25", zorder=3))
    colls = []
    for zorder, ids in zip((2, 4), side_layers(P, s.polys)):
        coll = PolyCollection(P[s.polys[ids]][:, :, :2], cmap=cmap, edgecolors=(0, 0, 0, 0.25), linewidths=0.2,
                              zorder=zorder)
        coll.set_array(values[ids])
        coll.set_clim(0.0, colour.vmax_mm)
        ax.add_collection(coll)
        colls.append(coll)
    ax.axvline(hi[0], color="0.2", lw=3.0)                   # the clamp
    ax.set_xlim(*xlim)
    ax.set_ylim(min(-0.5, (s.table_height_m or 0.0) * 1e3 - 1.0), hi[1] + 2.0)
    ax.set_aspect("equal")
    ax.set_xlabel("x [mm] (clamp at x = 0)")
    ax.set_ylabel("y [mm]")
    return colls[-1]


def _voltage(s: Scene3D, frame: int) -> float:
    return s.at(s.run_V, frame)


def _coin_x_mm(s: Scene3D, frame: int) -> float:
    return s.at(s.run_x, frame) * 1e3


def frame_title(s: Scene3D, frame: int) -> str:
    return (f"t = {s.fields.times[frame]:.3f} s, V = {_voltage(s, frame):.0f} V, "
            f"coin x = {_coin_x_mm(s, frame):.3f} mm")


def stage_picture(s: Scene3D, stage: str, frame: int, png: Path, dpi: int = 100) -> Path:
    """Side and 3/4 views of one frame into ``png`` (atomic), coloured by the actuation (the rest
    frame: by the gravity sag, on its own scale)."""
    title = dict(STAGES)[stage]
    colour = colouring(s, frame)
    fig = plt.figure(figsize=(12, 3.6))
    ax = fig.add_axes((0.06, 0.2, 0.42, 0.62))
    draw_side(ax, s, frame, colour=colour)
    ax.set_title("side view (from -z)", fontsize=10)
    _, elev, azim = VIEWS[1]
    ax = fig.add_axes((0.47, 0.0, 0.46, 0.92), projection="3d")
    coll = draw(ax, s, frame, elev, azim, colour=colour)
    ax.set_title("3/4 view (DEA see-through)", fontsize=10, y=0.97)
    fig.colorbar(coll, cax=fig.add_axes((0.94, 0.2, 0.012, 0.55)), label=colour.label)
    fig.suptitle(f"{s.setup}: {title} — {frame_title(s, frame)}", fontsize=11)
    save_png(fig, png, dpi)
    return Path(png)


def save_png(fig, png: Path, dpi: int) -> None:
    """Write a figure as PNG (atomic) and close it."""
    atomic_write(png, lambda p: fig.savefig(p, dpi=dpi, format="png", bbox_inches="tight"), suffix=".png")
    plt.close(fig)


def animation_picks(s: Scene3D, frames: int) -> np.ndarray:
    """Up to ``frames`` frame indices evenly spread over the run."""
    return np.unique(np.linspace(0, len(s.fields.times) - 1, max(2, frames)).astype(int))


def draw_xt(ax, s: Scene3D, frame: int) -> None:
    """The coin's x(t) over the whole run with a marker at the frame's time."""
    ax.plot(s.run_t, s.run_x * 1e3, color="0.35", lw=1.2)
    ax.plot([s.fields.times[frame]], [_coin_x_mm(s, frame)], "o", color=MARKER, ms=8, zorder=3)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("coin x [mm]")
    ax.set_title("coin position (dataset)", fontsize=9)
    ax.grid(alpha=0.3)


def animation_frame(s: Scene3D, frame: int):
    """One frame of the animation: the side view (coin and table visible) and the x(t) panel."""
    fig = plt.figure(figsize=(10.0, 3.4))
    ax = fig.add_axes((0.06, 0.17, 0.56, 0.66))
    colour = colouring(s, frame, sag_at_rest=False)
    coll = draw_side(ax, s, frame, colour=colour)
    fig.colorbar(coll, cax=fig.add_axes((0.63, 0.22, 0.008, 0.56)), label="|u − u(rest)| [mm]")
    ax = fig.add_axes((0.76, 0.17, 0.22, 0.66))
    draw_xt(ax, s, frame)
    fig.suptitle(f"{s.setup}  {frame_title(s, frame)}", fontsize=10)
    return fig


def animation(s: Scene3D, gif: Path, frames: int = 30, dpi: int = 70, progress: bool = True) -> Path:
    """The side view and the coin's x(t) (:func:`animation_frame`) of up to ``frames`` frames,
    evenly spread over the run, as an animated GIF (Pillow)."""
    images = []
    for i in tqdm(animation_picks(s, frames), desc="animation", unit="frame", disable=not progress or None):
        fig = animation_frame(s, int(i))
        buf = io.BytesIO()
        fig.savefig(buf, dpi=dpi, format="png")
        plt.close(fig)
        buf.seek(0)
        images.append(Image.open(buf).convert("RGB").convert("P", palette=Image.Palette.ADAPTIVE, colors=128))
    atomic_write(gif, lambda p: images[0].save(p, format="GIF", save_all=True, append_images=images[1:],
                                              duration=120, loop=0), suffix=".gif")
    return Path(gif)
