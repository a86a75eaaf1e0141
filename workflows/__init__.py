"""Workflows stage: the ``deapull`` command and the studies and reports it runs.

The public entry is :func:`main` (the ``deapull`` console script, :mod:`~deapull.workflows.cli`,
one ``cli_*`` module per group of commands). The studies run their cases on the one resumable
MPI runner (:mod:`~deapull.workflows.runner`): the setup sweep (:mod:`~deapull.workflows.sweep`), the fidelity
ladder (:mod:`~deapull.workflows.fidelity`) and the stability suite
(:mod:`~deapull.workflows.stability`). Importing this package loads neither dolfinx nor torch:
the commands import them when they run.
"""
from deapull.workflows import sweep
from deapull.workflows.cli import build_parser, main
from deapull.workflows.runner import Case, run_cases

__all__ = ["Case", "build_parser", "main", "run_cases", "sweep"]   # sweep: the module (sweep.sweep)
