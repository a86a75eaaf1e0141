"""Gmsh model of the unimorph DEA (and the coin, when the scene has one).

The DEA is two boxes (active stack and passive layer) fragmented so that they share a
conforming interface. ``mesh.cell = "hexahedron"`` meshes them as structured
(transfinite) hexahedra; ``"tetrahedron"`` splits the same structured grid into
tetrahedra. The coin is an unstructured tetrahedral cylinder. All elements are of
order ``mesh.order`` (second order by default: 27-node hexahedra, 10-node tetrahedra),
so the curved coin rim is represented and its mesh volume is within 0.5 % of πr²h.
``mesh.level`` multiplies every division by 2**level.
"""
from __future__ import annotations

import math
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import gmsh
import numpy as np

from deapull.io import atomic_write, write_json
from deapull.meshing import groups
from deapull.meshing.layout import Layout, layout
from deapull.scene import Scene

_TOL = 1e-6  # OCC pads bounding boxes by ~1e-7 m


@contextmanager
def gmsh_session(name: str = "deapull"):
    """An initialised, quiet gmsh session, always finalised."""
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add(name)
        yield gmsh.model
    finally:
        gmsh.finalize()


def _entities_in_box(dim, xmin, ymin, zmin, xmax, ymax, zmax):
    e = _TOL
    return [t for _, t in gmsh.model.getEntitiesInBoundingBox(xmin - e, ymin - e, zmin - e,
                                                              xmax + e, ymax + e, zmax + e, dim)]


def _divisions(scene: Scene) -> dict:
    """Element divisions of the modelled DEA (``z``: across the modelled width, half of
    ``n_width`` with ``mesh.symmetry = "half_z"``)."""
    m = scene.mesh
    k = 2 ** m.level
    z = m.n_width * k
    if m.symmetry == "half_z":
        z = (z + 1) // 2
    return {"x": m.n_length * k, "z": z, "active": m.n_active * k, "passive": m.n_passive * k}


def _z_range(scene: Scene) -> tuple[float, float]:
    """The modelled width: (-w/2, w/2), or (0, w/2) for the half model."""
    w = scene.dea.width_m
    return (0.0 if scene.mesh.symmetry == "half_z" else -w / 2), w / 2


def _progression(curve: int, count: int, ratio: float, axis: int, small_at: float) -> float:
    """Gmsh's progression coefficient that grades ``curve`` (``count`` elements along ``axis``,
    0 = x, 1 = y) by ``ratio`` = largest / smallest element, the smallest at the end nearer the
    coordinate ``small_at``: r = ratio^(1/(n-1)), inverted when the curve's parametrization starts
    at the other end. (Gmsh grades along the parametrization, which after the layers' fragment need
    not run from the curve's first boundary point: it does not on the layers' vertical edges.)"""
    if ratio == 1.0 or count < 2:
        return 1.0
    r = ratio ** (1.0 / (count - 1))
    box = gmsh.model.getBoundingBox(1, curve)
    lo, _ = gmsh.model.getParametrizationBounds(1, curve)
    start = gmsh.model.getValue(1, curve, [lo[0]])[axis]
    mid = 0.5 * (box[axis] + box[axis + 3])
    return r if (start < mid) == (small_at < mid) else 1.0 / r


def _x_progression(scene: Scene, curve: int, count: int) -> float:
    """Along an x curve for ``mesh.x_grading`` (element length at the clamp / at the free end):
    the small elements at the free end x = -L."""
    return _progression(curve, count, scene.mesh.x_grading, 0, -scene.dea.length_m)


def _y_progression(scene: Scene, lay: Layout, curve: int, count: int) -> float:
    """Along a through-thickness curve for ``mesh.underside_grading``: in the bottom layer, the
    small elements on the underside (y = y_bottom); 1 elsewhere."""
    if abs(gmsh.model.getBoundingBox(1, curve)[1] - lay.y_bottom_m) > _TOL:
        return 1.0
    return _progression(curve, count, scene.mesh.underside_grading, 1, lay.y_bottom_m)


def x_intervals(scene: Scene) -> list[tuple[float, float, int, bool]]:
    """The DEA's x intervals as (x0, x1, divisions, graded): the tip zone ``mesh.tip_zone_m``
    from the free end with its own uniform ``mesh.tip_zone_divisions`` (× 2^level), and the
    rest with ``mesh.n_length`` (× 2^level; graded by ``mesh.x_grading``); one interval without
    a tip zone. With a rounded free edge the tip zone starts with the O-grid's two columns (the
    edge's radius) and ``tip_zone_divisions`` mesh the rest of it."""
    m, L = scene.mesh, scene.dea.length_m
    k = 2 ** m.level
    if not m.tip_zone_m:
        return [(-L, 0.0, m.n_length * k, True)]
    rest = (-L + m.tip_zone_m, 0.0, m.n_length * k, True)
    edge = free_edge(scene)
    if edge is None:
        return [(-L, -L + m.tip_zone_m, m.tip_zone_divisions * k, False), rest]
    r, a = edge.radius, edge.inner
    return [(-L, -L + r - a, edge.divisions, False), (-L + r - a, -L + r, edge.divisions, False),
            (-L + r, -L + m.tip_zone_m, m.tip_zone_divisions * k, False), rest]


@dataclass(frozen=True)
class FreeEdge:
    """The rounded free bottom edge's O-grid (the corner square of side ``radius`` at the free end's
    underside, in the x-y plane, extruded along z): an inner square of side ``inner`` at the arc's
    centre and two blocks between it and the arc, each ``divisions`` along its half of the arc and
    ``divisions`` from the arc to the inner square, which is ``divisions`` each way."""
    radius: float
    inner: float
    divisions: int


def free_edge(scene: Scene) -> FreeEdge | None:
    """The O-grid of ``dea.free_edge_radius_m`` (None for a sharp edge): the inner square half the
    radius, ``mesh.free_edge_divisions`` x 2^level divisions on every side of its blocks."""
    r = scene.dea.free_edge_radius_m
    if not r:
        return None
    return FreeEdge(radius=r, inner=r / 2, divisions=scene.mesh.free_edge_divisions * 2 ** scene.mesh.level)


def y_intervals(scene: Scene, lay: Layout) -> list[tuple[float, float, int, str]]:
    """The DEA's through-thickness intervals as (y0, y1, divisions, layer), bottom up: one per layer
    with its ``mesh.n_active`` / ``n_passive`` (x 2^level), the bottom layer cut at the free edge's
    O-grid (``dea.free_edge_radius_m``) into the arc's outer and inner rows and the rest."""
    n = _divisions(scene)
    layers = sorted((("active", lay.active_y_m), ("passive", lay.passive_y_m)), key=lambda kv: kv[1][0])
    out = [(y0, y1, n[name], name) for name, (y0, y1) in layers]
    edge = free_edge(scene)
    if edge is None:
        return out
    y0, y1, count, name = out[0]
    r, a, h = edge.radius, edge.inner, (y1 - y0) / count
    return [(y0, y0 + r - a, edge.divisions, name), (y0 + r - a, y0 + r, edge.divisions, name),
            (y0 + r, y1, max(1, round((y1 - y0 - r) / h)), name), *out[1:]]


def rim_band(scene: Scene) -> tuple[float, float] | None:
    """The band a <= |z| <= b meshed with ``mesh.rim_band_divisions``: ``mesh.rim_band_m`` as given, or,
    with ``mesh.rim_band_width_m``, placed from the scene's coin (or stop): centred on the |z| where the
    free edge at rest (a distance c = ``center_from_tip_m`` from the coin's axis) crosses the middle of
    the rim, rho = radius - edge_radius / 2, i.e. z = sqrt(rho^2 - c^2); clipped to the width, with a
    quarter of the band's width kept clear of the mid-plane and of the side face. None: no band."""
    m = scene.mesh
    if m.rim_band_m:
        return tuple(m.rim_band_m)
    obstacle = scene.coin or scene.stop
    if not m.rim_band_width_m or obstacle is None:
        return None
    w, half = m.rim_band_width_m, scene.dea.width_m / 2
    rho = obstacle.radius_m - obstacle.edge_radius_m / 2
    zc = math.sqrt(max(rho ** 2 - obstacle.center_from_tip_m ** 2, 0.0))
    a = min(max(zc - w / 2, w / 4), half - 1.25 * w)
    if a <= 0:
        raise ValueError(f"mesh.rim_band_width_m = {w!r}: the band does not fit in the half width {half!r}")
    return a, a + w


def z_intervals(scene: Scene) -> list[tuple[float, float, int]]:
    """The modelled width's z intervals as (z0, z1, divisions): without ``mesh.rim_band_m`` one
    interval with the width's divisions; with a band (|z| in [a, b], where the tip crosses the
    coin's rim) the band gets ``mesh.rim_band_divisions`` and the pieces beside it their share
    of ``mesh.n_width`` by length (at least 1), all × 2^level, mirrored for the full model."""
    m = scene.mesh
    k = 2 ** m.level
    zmin, zmax = _z_range(scene)
    band = rim_band(scene)
    if band is None:
        return [(zmin, zmax, _divisions(scene)["z"])]
    a, b = band
    half = scene.dea.width_m / 2
    per_m = m.n_width / (2 * half)

    def share(length):
        return max(1, round(per_m * length)) * k

    right = [(0.0, a, share(a)), (a, b, m.rim_band_divisions * k), (b, half, share(half - b))]
    if m.symmetry == "half_z":
        return right
    left = [(-z1, -z0, n) for z0, z1, n in reversed(right)]
    inner = [(-a, a, share(2 * a))]
    return left[:2] + inner + right[1:]


def _add_dea(scene: Scene, lay: Layout) -> dict:
    """Add the DEA as boxes, one per x, y and z interval (tip zone, rim band, layers), the rounded
    free edge's O-grid in place of the corner's boxes; fragment them into one conforming body and
    return the volume tags by layer name."""
    occ = gmsh.model.occ
    xs, ys, zs = x_intervals(scene), y_intervals(scene, lay), z_intervals(scene)
    edge = free_edge(scene)
    pieces = {"active": [], "passive": []}
    for iy, (y0, y1, _, name) in enumerate(ys):
        for ix, (x0, x1, _, _) in enumerate(xs):
            if edge is not None and ix < 2 and iy < 2 and not (ix == 1 and iy == 1):
                continue        # the corner's boxes: the O-grid's two outer blocks replace them
            pieces[name] += [occ.addBox(x0, y0, z0, x1 - x0, y1 - y0, z1 - z0) for z0, z1, _ in zs]
    if edge is not None:
        pieces[ys[0][3]] += _add_free_edge_blocks(edge, lay, zs)
    objects = [(3, t) for t in pieces["active"]]
    tools = [(3, t) for t in pieces["passive"]]
    _, children = occ.fragment(objects, tools)
    occ.synchronize()
    out = {"active": [], "passive": []}
    for (dim, tag), kids in zip(objects + tools, children):
        out["active" if (dim, tag) in objects else "passive"] += [t for _, t in kids]
    return out


def _add_free_edge_blocks(edge: FreeEdge, lay: Layout, zs) -> list[int]:
    """The O-grid's two outer blocks in the corner square of the free end's underside: each between
    the inner square and one half of the quarter-circle arc (centre c, from the end face through the
    45 degree point M to the underside), extruded over every z interval; their volume tags."""
    occ = gmsh.model.occ
    r, a = edge.radius, edge.inner
    cx, cy = -lay.length_m + r, lay.y_bottom_m + r
    s = r / math.sqrt(2.0)
    volumes = []
    for z0, z1, _ in zs:
        c = occ.addPoint(cx, cy, z0)
        end_face, under, mid = occ.addPoint(cx - r, cy, z0), occ.addPoint(cx, cy - r, z0), occ.addPoint(cx - s, cy - s, z0)
        inner = occ.addPoint(cx - a, cy - a, z0)
        top, side = occ.addPoint(cx - a, cy, z0), occ.addPoint(cx, cy - a, z0)
        for corner, arc_end in ((top, end_face), (side, under)):
            arc = occ.addCircleArc(arc_end, c, mid)
            loop = occ.addCurveLoop([occ.addLine(corner, arc_end), arc, occ.addLine(mid, inner),
                                     occ.addLine(inner, corner)])
            face = occ.addPlaneSurface([loop])
            out = occ.extrude([(2, face)], 0.0, 0.0, z1 - z0)
            volumes += [t for d, t in out if d == 3]
        occ.remove([(0, c)])
    return volumes


def _structure_dea(scene: Scene, lay: Layout, vols: dict) -> None:
    """Transfinite curves, surfaces and volumes on the DEA boxes (and nothing else)."""
    xs, ys, zs = x_intervals(scene), y_intervals(scene, lay), z_intervals(scene)
    edge = free_edge(scene)

    def interval(lo, hi, intervals):
        for iv in intervals:
            if abs(iv[0] - lo) < _TOL and abs(iv[1] - hi) < _TOL:
                return iv
        raise RuntimeError(f"curve [{lo}, {hi}] matches no mesh interval")

    volumes = [(3, t) for tags in vols.values() for t in tags]
    surfaces = sorted({abs(t) for _, t in gmsh.model.getBoundary(volumes, combined=False, oriented=False)})
    curves = sorted({abs(t) for _, t in gmsh.model.getBoundary([(2, s) for s in surfaces], combined=False,
                                                                oriented=False)})
    for c in curves:
        x0, y0, z0, x1, y1, z1 = gmsh.model.getBoundingBox(1, c)
        if x1 - x0 > _TOL and y1 - y0 <= _TOL:
            _, _, count, graded = interval(x0, x1, xs)
            progression = _x_progression(scene, c, count) if graded else 1.0
            gmsh.model.mesh.setTransfiniteCurve(c, count + 1, "Progression", progression)
            continue
        elif z1 - z0 > _TOL:
            count = interval(z0, z1, zs)[2]
        elif y1 - y0 > _TOL and abs(x1 - x0) <= _TOL:
            count = interval(y0, y1, ys)[2]
            gmsh.model.mesh.setTransfiniteCurve(c, count + 1, "Progression", _y_progression(scene, lay, c, count))
            continue
        else:   # in the rounded free edge's O-grid: half of the arc, or the diagonal from M inward
            count = edge.divisions
        gmsh.model.mesh.setTransfiniteCurve(c, count + 1)
    for s in surfaces:
        gmsh.model.mesh.setTransfiniteSurface(s)
        if scene.mesh.cell == "hexahedron":
            gmsh.model.mesh.setRecombine(2, s)
    for _, v in volumes:
        gmsh.model.mesh.setTransfiniteVolume(v)


def _add_coin(scene: Scene, lay: Layout) -> int:
    c = scene.coin
    tag = gmsh.model.occ.addCylinder(lay.obstacle_center_x_m, 0.0, 0.0, 0.0, c.height_m, 0.0, c.radius_m)
    gmsh.model.occ.synchronize()
    return tag


def _tag_groups(scene: Scene, lay: Layout, vols: dict, coin_tag) -> None:
    L, w = lay.length_m, lay.width_m
    ytop = lay.y_bottom_m + lay.thickness_m
    zmin, _ = _z_range(scene)

    def add(dim, entities, tag, name):
        gmsh.model.addPhysicalGroup(dim, entities, tag)
        gmsh.model.setPhysicalName(dim, tag, name)
    for name, tags in vols.items():
        add(3, tags, groups.VOLUMES[name], name)
    dea_faces = {abs(t) for _, t in gmsh.model.getBoundary([(3, t) for ts in vols.values() for t in ts],
                                                            combined=False,
                                                            oriented=False)}

    def dea_box(*box):
        return [t for t in _entities_in_box(2, *box) if t in dea_faces]

    add(2, dea_box(0, lay.y_bottom_m, -w / 2, 0, ytop, w / 2), groups.CLAMP, "clamp")
    if scene.mesh.symmetry == "half_z":
        add(2, dea_box(-L, lay.y_bottom_m, zmin, 0, ytop, zmin), groups.SYMMETRY, "symmetry")
    (a0, a1) = lay.active_y_m
    add(2, dea_box(-L, a1, -w / 2, 0, a1, w / 2), groups.ELECTRODE_TOP, "electrode_top")
    add(2, dea_box(-L, a0, -w / 2, 0, a0, w / 2), groups.ELECTRODE_BOTTOM, "electrode_bottom")
    y0 = lay.y_bottom_m
    contact = dea_box(-L, y0, -w / 2, 0, y0, w / 2)
    r = scene.dea.free_edge_radius_m
    if r > 0:   # the rounded free edge, which rides onto the coin's rim, is part of the underside
        contact += [t for t in dea_box(-L, y0, -w / 2, -L + r, y0 + r, w / 2) if gmsh.model.getType(2, t) != "Plane"]
    add(2, contact, groups.DEA_CONTACT, "dea_contact")
    if coin_tag is not None:
        add(3, [coin_tag], groups.COIN, "coin")
        x0, r, h = lay.obstacle_center_x_m, scene.coin.radius_m, scene.coin.height_m
        add(2, _entities_in_box(2, x0 - r, h, -r, x0 + r, h, r), groups.COIN_TOP, "coin_top")
        add(2, _entities_in_box(2, x0 - r, 0, -r, x0 + r, 0, r), groups.COIN_BOTTOM, "coin_bottom")


def build_model(scene: Scene) -> None:
    """Build and mesh the scene in the current gmsh model (its layout computed once here)."""
    lay = layout(scene)
    vols = _add_dea(scene, lay)
    coin_tag = _add_coin(scene, lay) if scene.coin is not None else None
    _structure_dea(scene, lay, vols)
    if coin_tag is not None:
        size = scene.mesh.coin_size_m / 2 ** scene.mesh.level
        coin_points = gmsh.model.getBoundary([(3, coin_tag)], combined=False, recursive=True)
        gmsh.model.mesh.setSize(coin_points, size)
    _tag_groups(scene, lay, vols, coin_tag)
    gmsh.option.setNumber("Mesh.ElementOrder", scene.mesh.order)
    gmsh.option.setNumber("Mesh.SecondOrderIncomplete", 0)
    gmsh.option.setNumber("Mesh.HighOrderOptimize", 0)
    gmsh.model.mesh.generate(3)
    if scene.mesh.order > 1:
        gmsh.model.mesh.setOrder(scene.mesh.order)


def _group_measure(dim: int, tag: int) -> tuple[float, float]:
    """Mesh measure (volume or area) of a physical group, by Gauss quadrature on its elements,
    and its worst element quality min(det J) / max(det J) over the Gauss points (1 = affine)."""
    total, quality = 0.0, 1.0
    for entity in gmsh.model.getEntitiesForPhysicalGroup(dim, tag):
        types, _, _ = gmsh.model.mesh.getElements(dim, entity)
        for etype in types:
            pts, weights = gmsh.model.mesh.getIntegrationPoints(etype, "Gauss6")
            _, dets, _ = gmsh.model.mesh.getJacobians(etype, pts, entity)
            dets = np.asarray(dets).reshape(-1, len(weights))
            total += float(np.sum(np.abs(dets) @ np.asarray(weights)))
            quality = min(quality, float(np.min(dets.min(axis=1) / np.abs(dets).max(axis=1))))
    return total, quality


def summarise() -> dict:
    """Cells, nodes and measure per physical group, and the minimum element quality."""
    out = {"groups": {}}
    qualities = []
    for dim, tag in gmsh.model.getPhysicalGroups():
        name = gmsh.model.getPhysicalName(dim, tag)
        n_cells, nodes = 0, set()
        for entity in gmsh.model.getEntitiesForPhysicalGroup(dim, tag):
            types, etags, enodes = gmsh.model.mesh.getElements(dim, entity)
            for et, nd in zip(etags, enodes):
                n_cells += len(et)
                nodes.update(nd.tolist())
        measure, quality = _group_measure(dim, tag)
        if dim == 3:
            qualities.append(quality)
        key = "volume_m3" if dim == 3 else "area_m2"
        out["groups"][name] = {"dim": dim, "id": tag, "cells": n_cells, "nodes": len(nodes), key: measure}
    out["min_quality_detj_ratio"] = min(qualities) if qualities else None
    return out


def write_mesh(scene: Scene, out_dir: str | Path) -> tuple[Path, dict]:
    """Mesh the scene into ``out_dir/mesh.msh`` and ``out_dir/mesh.json`` (atomically).

    Returns the path of the ``.msh`` file and the summary.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with gmsh_session(scene.scene.name):
        build_model(scene)
        summary = summarise()
        summary.update(scene=scene.scene.name, setup=scene.setup, cell=scene.mesh.cell,
                       order=scene.mesh.order, level=scene.mesh.level, divisions=_divisions(scene))
        if scene.coin is not None:
            c = scene.coin
            exact = math.pi * c.radius_m ** 2 * c.height_m
            summary["coin_volume_exact_m3"] = exact
            summary["coin_volume_rel_error"] = summary["groups"]["coin"]["volume_m3"] / exact - 1.0
        msh = atomic_write(out / "mesh.msh", gmsh.write, suffix=".msh")
    write_json(out / "mesh.json", summary, indent=2)
    return msh, summary
