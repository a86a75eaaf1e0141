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
