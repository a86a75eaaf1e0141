"""deapull: an open reproduction of FEM-trained physics-informed DEA models (dolfinx + torch).

This package is the ground floor that every stage stands on: the scene schema and the
shipped scenes (:mod:`deapull.scene`), the one error class for bad input
(:mod:`deapull.errors`), the dataset contract between the FEM and its readers
(:mod:`deapull.dataset`), provenance (:mod:`deapull.provenance`) and atomic file and table
output (:mod:`deapull.io`). The stages are its sub-packages, each importing only downward::

    deapull.workflows   CLI, study harnesses, reports       (repository folder workflows/)
    deapull.control     controllers and plants              (control/)
    deapull.surrogate   torch surrogates                    (surrogate/)
    deapull.fem_solver  dolfinx solver                      (fem_solver/)
    deapull.meshing     gmsh meshes                         (meshing/)
    deapull.scene, .dataset, .geometry, .errors, .io, .provenance (deapull/)

``tests/deapull/test_layers.py`` runs the import-linter contract of ``pyproject.toml`` that
keeps it so, and the check that no modules import each other in a circle
(``scripts/check_layers.py``). Each package names its public API in ``__all__``; this one's
is its modules.
"""
from deapull import dataset, errors, geometry, io, protocol, provenance, scene

__version__ = "0.1.0"
__all__ = ["__version__", "dataset", "errors", "geometry", "io", "protocol", "provenance", "scene"]
