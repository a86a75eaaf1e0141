"""Pictures of the deforming DEA and the coin from the solver's field output (off-screen).

``deapull solve ... --fields-every N`` writes the displacement of the DEA every N accepted
steps as XDMF (``<setup>_fields.xdmf``, the geometry and topology once, one ``Time`` per
frame) with its data in HDF5 (``<setup>_fields.h5``). This module reads both with the
standard library's XML parser and h5py (no dolfinx, no VTK), extracts the boundary faces
of the mesh (hexahedra of 8 or 27 nodes, tetrahedra of 4 or 10) and draws them with
matplotlib's ``Poly3DCollection``, coloured by the displacement magnitude |u| (mm). The
coin is the rigid disc of the scene (radius, height, centre from the tip), shifted by the
coin's x(t) from the run's dataset (``<setup>.nc`` beside the fields). A half model
(``mesh.symmetry = "half_z"``) is mirrored to the whole DEA.

Stages (the paper's Fig. 4): *at rest* is the first frame (the DEA settled on the coin
under gravity, V = 0), *static stage* the last frame before the coin starts to slide
(dataset variable ``stick``), *kinetic stage* the last frame. The animation is an
animated GIF written with Pillow (matplotlib's own image dependency).
"""
from __future__ import annotations

import io
import logging

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import h5py
import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.collections import PolyCollection  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402
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


def _hex_lattice(points: np.ndarray, cell: np.ndarray, n: int) -> np.ndarray:
    """(n, n, n) array of the cell's node ids by position in its (axis-aligned) reference box."""
    X = points[cell]
    lo, hi = X.min(0), X.max(0)
    idx = np.rint((X - lo) / np.where(hi > lo, hi - lo, 1.0) * (n - 1)).astype(int)
    grid = -np.ones((n, n, n), dtype=np.int64)
    grid[idx[:, 0], idx[:, 1], idx[:, 2]] = cell
    if (grid < 0).any():
        raise InputError("field mesh: a hexahedron is not an axis-aligned box in the reference configuration; "
                         "cannot place its nodes")
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
            g = _hex_lattice(points, cell, n)
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
    centre_x_m: float
    radius_m: float
    height_m: float


def run_scene(run_attrs: dict):
    """The run's resolved scene (from the dataset's ``scene_toml``), None when it has none."""
    text = run_attrs.get("scene_toml", "")
    return scenes.from_resolved_toml(text) if text else None


def coin_geometry(sc) -> CoinGeometry | None:
    """The coin of a scene, None without a coin (or scene)."""
    if sc is None or sc.coin is None:
        return None
    return CoinGeometry(-sc.dea.length_m + sc.coin.center_from_tip_m, sc.coin.radius_m, sc.coin.height_m)


def mirror_z(points: np.ndarray, polys: list) -> tuple[np.ndarray, list]:
    """A half model (z >= 0, mesh.symmetry = half_z) made whole: the nodes mirrored to -z
    (ids + n), the boundary polygons doubled, those on the symmetry plane dropped."""
    n = len(points)
    scale = float(np.ptp(points[:, 2])) or 1.0
    on_plane = np.abs(points[:, 2]) <= 1e-9 * scale
    kept = [p for p in polys if not on_plane[list(p)].all()]
    return np.vstack([points, points * [1.0, 1.0, -1.0]]), kept + [tuple(i + n for i in p[::-1]) for p in kept]


@dataclass(frozen=True)
class Scene3D:
    """Everything a picture needs: the field frames, boundary polygons, the run (x, stick)."""
    fields: Fields
    polys: np.ndarray           # (p, k) node ids
    coin: CoinGeometry | None
    run_t: np.ndarray
    run_x: np.ndarray
    run_V: np.ndarray
    stick: np.ndarray | None
    setup: str
    umax_mm: float
    points: np.ndarray          # reference node coordinates drawn (m): the mesh's, mirrored for a half model
    mirrored: bool = False

    def displacement(self, frame: int) -> np.ndarray:
        """Nodal displacement (m) of a frame, on :attr:`points`."""
        u = self.fields.displacement(frame)
        return np.vstack([u, u * [1.0, 1.0, -1.0]]) if self.mirrored else u


def load_scene3d(xdmf, run_path=None) -> Scene3D:
    """Fields + their run's dataset (default: ``<setup>.nc`` beside ``<setup>_fields.xdmf``)."""
    fields = read_fields(xdmf)
    xdmf = Path(xdmf)
    if run_path is None:
        run_path = xdmf.with_name(xdmf.name.replace("_fields.xdmf", ".nc"))
    run = dataset.read(run_path, variables=("t", "x", "V"), optional=("stick",))
    polys = boundary_faces(fields.points, fields.cells, fields.cell_type)
    sc = run_scene(run.attrs)
    mirrored = sc is not None and getattr(sc.mesh, "symmetry", "none") == "half_z"
    points = fields.points
    if mirrored:
        points, polys = mirror_z(points, polys)
    umax = max(float(np.linalg.norm(fields.displacement(i), axis=1).max()) for i in
               np.unique(np.linspace(0, len(fields.times) - 1, 12).astype(int)))
    return Scene3D(fields, np.array(polys, dtype=np.int64), coin_geometry(sc), run.columns["t"], run.columns["x"],
                   run.columns["V"], run.columns.get("stick"), str(run.attrs.get("setup", "")), umax * 1e3, points,
                   mirrored)


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


def _coin_polys(c: CoinGeometry, x_shift: float, n: int = 36) -> list[np.ndarray]:
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    ring = np.stack([c.centre_x_m + x_shift + c.radius_m * np.cos(a), c.radius_m * np.sin(a)], axis=1) * 1e3
    bottom = np.column_stack([ring[:, 0], ring[:, 1], np.zeros(n)])
    top = np.column_stack([ring[:, 0], ring[:, 1], np.full(n, c.height_m * 1e3)])
    sides = [np.array([bottom[i], bottom[(i + 1) % n], top[(i + 1) % n], top[i]]) for i in range(n)]
    return [bottom, top, *sides]


def draw(ax, s: Scene3D, frame: int, elev: float, azim: float, cmap="viridis"):
    """Draw one frame on a 3D axes; returns the polygon collection (for a colour bar)."""
    u = s.displacement(frame)
    P = (s.points + u) * 1e3
    P = P[:, [0, 2, 1]]                      # plot (x, z, y): y is up
    mag = np.linalg.norm(u, axis=1)[s.polys].mean(axis=1) * 1e3
    coll = Poly3DCollection(P[s.polys], cmap=cmap, edgecolors=(0, 0, 0, 0.25), linewidths=0.2)
    coll.set_array(mag)
    coll.set_clim(0.0, max(s.umax_mm, 1e-9))
    ax.add_collection3d(coll)
    t = float(s.fields.times[frame])
    if s.coin is not None:
        shift = float(np.interp(t, s.run_t, s.run_x))
        ax.add_collection3d(Poly3DCollection(_coin_polys(s.coin, shift), facecolors=(0.72, 0.72, 0.75, 0.9),
                                             edgecolors=(0.3, 0.3, 0.3, 0.15), linewidths=0.2))
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


def draw_side(ax, s: Scene3D, frame: int, cmap="viridis"):
    """Side view: the boundary polygons projected on the x-y plane, far ones (+z) first."""
    u = s.displacement(frame)
    P = (s.points + u) * 1e3
    order = np.argsort(-P[s.polys][:, :, 2].mean(axis=1))     # the viewer looks from -z
    mag = np.linalg.norm(u, axis=1)[s.polys].mean(axis=1) * 1e3
    lo, hi = s.points.min(0) * 1e3, s.points.max(0) * 1e3
    if s.coin is not None:
        x0 = (s.coin.centre_x_m - s.coin.radius_m) * 1e3 + _coin_x_mm(s, frame)
        ax.add_patch(Rectangle((x0, 0.0), 2 * s.coin.radius_m * 1e3, s.coin.height_m * 1e3,
                               facecolor=(0.72, 0.72, 0.75), edgecolor="0.3", zorder=2))
    coll = PolyCollection(P[s.polys][order][:, :, :2], cmap=cmap, edgecolors=(0, 0, 0, 0.25), linewidths=0.2,
                          zorder=3)
    coll.set_array(mag[order])
    coll.set_clim(0.0, max(s.umax_mm, 1e-9))
    ax.add_collection(coll)
    ax.axhline(0.0, color="0.4", lw=1.0)
    ax.axvline(hi[0], color="0.2", lw=3.0)                   # the clamp
    ax.set_xlim(lo[0] - 4.0, hi[0] + 2.0)
    ax.set_ylim(-0.5, hi[1] + 2.0)
    ax.set_aspect("equal")
    ax.set_xlabel("x [mm] (clamp at x = 0)")
    ax.set_ylabel("y [mm]")
    return coll


def _voltage(s: Scene3D, frame: int) -> float:
    return float(np.interp(s.fields.times[frame], s.run_t, s.run_V))


def _coin_x_mm(s: Scene3D, frame: int) -> float:
    return float(np.interp(s.fields.times[frame], s.run_t, s.run_x)) * 1e3


def stage_picture(s: Scene3D, stage: str, frame: int, png: Path, dpi: int = 100) -> Path:
    """Side and 3/4 views of one frame, coloured by |u|, into ``png`` (atomic)."""
    title = dict(STAGES)[stage]
    fig = plt.figure(figsize=(12, 3.6))
    ax = fig.add_axes((0.06, 0.2, 0.42, 0.62))
    draw_side(ax, s, frame)
    ax.set_title("side view (from -z)", fontsize=10)
    _, elev, azim = VIEWS[1]
    ax = fig.add_axes((0.47, 0.0, 0.46, 0.92), projection="3d")
    coll = draw(ax, s, frame, elev, azim)
    ax.set_title("3/4 view", fontsize=10, y=0.97)
    fig.colorbar(coll, cax=fig.add_axes((0.94, 0.2, 0.012, 0.55)), label="|u| [mm]")
    fig.suptitle(f"{s.setup}: {title} — t = {s.fields.times[frame]:.3f} s, V = {_voltage(s, frame):.0f} V, "
                 f"coin x = {_coin_x_mm(s, frame):.3f} mm", fontsize=11)
    atomic_write(png, lambda p: fig.savefig(p, dpi=dpi, format="png", bbox_inches="tight"), suffix=".png")
    plt.close(fig)
    return Path(png)


def animation(s: Scene3D, gif: Path, frames: int = 30, dpi: int = 70, progress: bool = True) -> Path:
    """3/4 view of up to ``frames`` frames, evenly spread over the run, as an animated GIF (Pillow)."""
    picks = np.unique(np.linspace(0, len(s.fields.times) - 1, max(2, frames)).astype(int))
    images = []
    _, elev, azim = VIEWS[1]
    for i in tqdm(picks, desc="animation", unit="frame", disable=not progress or None):
        fig = plt.figure(figsize=(6.4, 3.6))
        ax = fig.add_axes((0.0, 0.0, 1.0, 0.92), projection="3d")
        draw(ax, s, int(i), elev, azim)
        ax.set_title(f"{s.setup}  t = {s.fields.times[i]:.3f} s   V = {_voltage(s, int(i)):.0f} V   "
                     f"coin x = {_coin_x_mm(s, int(i)):.3f} mm", fontsize=9)
        buf = io.BytesIO()
        fig.savefig(buf, dpi=dpi, format="png")
        plt.close(fig)
        buf.seek(0)
        images.append(Image.open(buf).convert("RGB").convert("P", palette=Image.Palette.ADAPTIVE, colors=128))
    atomic_write(gif, lambda p: images[0].save(p, format="GIF", save_all=True, append_images=images[1:],
                                              duration=120, loop=0), suffix=".gif")
    return Path(gif)
