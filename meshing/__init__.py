"""Meshing stage: a scene → a gmsh ``.msh`` of the DEA (and the coin) with named physical groups.

:func:`layout.layout() <deapull.meshing.layout.layout>` says where everything sits (one place for the geometry
conventions, computed once per scene); :func:`~deapull.meshing.build.write_mesh` builds and
writes the mesh and its summary; :mod:`~deapull.meshing.groups` holds the physical-group ids.
"""
from deapull.meshing import groups, layout
from deapull.meshing.build import build_model, write_mesh
from deapull.meshing.layout import Layout

__all__ = ["Layout", "build_model", "groups", "layout", "write_mesh"]   # layout: the module (layout.layout)
