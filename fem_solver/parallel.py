"""MPI helpers for the rank-group harnesses (sweep, fidelity ladder, stability suite)."""
from __future__ import annotations

import time

#: seconds between checks of a pending barrier
POLL_S = 0.05


def idle_barrier(comm, poll_s: float = POLL_S) -> None:
    """A barrier that sleeps while it waits.

    Open MPI's blocking ``Barrier`` polls at full speed: a rank whose share of the cases is
    done would keep a core busy until the slowest group finishes, stealing it from the
    solves still running when the ranks outnumber the free cores. This one posts a
    non-blocking barrier and tests it every ``poll_s`` seconds.
    """
    request = comm.Ibarrier()
    while not request.Test():
        time.sleep(poll_s)


def initialise_petsc(comm) -> None:
    """Import dolfinx (and so initialise PETSc) on every rank before the groups split.

    PETSc's initialisation is collective on ``MPI_COMM_WORLD``: left to the first solve, it
    runs only on the ranks that have a case, and when a rank has none (fewer cases left than
    groups, as on a resumed run) the solving ranks wait for it forever.
    """
    import dolfinx.fem.petsc  # noqa: F401
    comm.Barrier()
