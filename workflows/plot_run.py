"""Figures of FEM datasets (matplotlib, Agg): the paper's Fig. 5 view of one run."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import xarray as xr  # noqa: E402

from deapull.errors import InputError  # noqa: E402


def plot_run(dataset_path, png_path) -> Path:
    """x(t), u(t), Fx/Fy(t) and V(t) of one dataset, stick/slip shaded."""
    dataset_path, png_path = Path(dataset_path), Path(png_path)
    if not dataset_path.is_file():
        raise InputError(f"dataset {str(dataset_path)!r}: not found")
    ds = xr.open_dataset(dataset_path, engine="h5netcdf")
    t = ds.t.values
    fig, ax = plt.subplots(4, 1, figsize=(7, 9), sharex=True)
    ax[0].plot(t, ds.x * 1e3)
    ax[0].set_ylabel("coin x [mm]\n(+x: toward the clamp)")
    ax[1].plot(t, ds.u * 1e3)
    ax[1].set_ylabel("coin u [mm/s]")
    ax[2].plot(t, ds.Fx * 1e3, label="Fx")
    ax[2].plot(t, ds.Fy * 1e3, label="Fy (pressing)")
    ax[2].set_ylabel("force on coin [mN]")
    ax[2].legend()
    ax[3].plot(t, ds.V)
    ax[3].set_ylabel("V [V]")
    ax[3].set_xlabel("t [s]")
    slip = ds.stick.values == 0
    if slip.any():
        first, last = int(slip.argmax()), len(slip) - 1 - int(slip[::-1].argmax())
        for a in ax:
            a.axvspan(t[max(first - 1, 0)], t[last], color="0.9", zorder=0)
    x = ds.x.values
    motion = ds.attrs.get("coin_motion") or ("toward -x (away from the clamp)" if x.min() < -abs(x.max())
                                              else "toward +x (toward the clamp)")
    fig.suptitle(f"{ds.attrs.get('scene', '')} {ds.attrs.get('setup', '')}: {ds.sizes['step']} points, "
                 f"travel {float(abs(x).max()) * 1e3:.3f} mm {motion}\n(shaded: kinetic stage)")
    fig.tight_layout()
    png_path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png_path, dpi=110)
    plt.close(fig)
    return png_path
