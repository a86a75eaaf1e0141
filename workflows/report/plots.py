"""The figures the report draws itself (matplotlib, Agg); the DEA pictures are in :mod:`.pictures`."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from deapull.io import atomic_write  # noqa: E402


def plot_sweep(runs: dict, png: Path) -> Path:
    """x, Fy and Fx against t of every setup's run (``runs``: setup → dataset.Run) on shared axes."""
    fig, ax = plt.subplots(3, 1, figsize=(8, 8.5), sharex=True)
    cmap = plt.get_cmap("tab10")
    for i, (name, run) in enumerate(runs.items()):
        c = run.columns
        style = dict(color=cmap(i % 10), lw=1.2, label=name, ls="-" if i % 2 == 0 else "--")
        ax[0].plot(c["t"], c["x"] * 1e3, **style)
        ax[1].plot(c["t"], c["Fy"] * 1e3, **style)
        ax[2].plot(c["t"], c["Fx"] * 1e3, **style)
    ax[0].set_ylabel("coin x [mm]")
    ax[1].set_ylabel("Fy (pressing) [mN]")
    ax[2].set_ylabel("Fx [mN]")
    ax[2].set_xlabel("t [s] (V = 400 t V)")
    ax[0].legend(ncol=4, fontsize=8)
    for a in ax:
        a.grid(alpha=0.3)
    fig.suptitle("The 8-setup sweep (the paper's Fig. 4 stages): static friction, then the coin slides toward −x")
    fig.tight_layout()
    atomic_write(png, lambda p: fig.savefig(p, dpi=100, format="png"), suffix=".png")
    plt.close(fig)
    return png
