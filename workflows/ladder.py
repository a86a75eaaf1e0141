"""Trained surrogates as rows of the FEM fidelity ladder (``deapull fidelity --surrogate DIR``).

The ladder (fem_solver/fidelity.py) plots the error of each FEM discretisation against its
run time, all measured against one reference rung. A surrogate belongs on the same axes: it
is another way to get x(t) and Fy(t) of the same setup, much faster. Each model folder
(written by ``deapull train`` or ``deapull experiments``) is rolled out once over the
setup's sweep dataset — the scene's own 1 s ramp at the sweep's steps, the coin of that
setup — and the rollout is written as a small dataset (t, x, Fy, with the dataset
contract's units and ``complete = 1``: :mod:`deapull.dataset`) that the ladder's report
compares with its reference like any rung. Its run time is the rollout's (the best of
three, after a warm-up), in the ladder's ``solve_s`` column.

A surrogate's error against the reference includes the error of the FEM it was trained on
(the shipped mesh) plus its own; the black boxes have no Fy (their rollout file holds t and
x only), so their error is the x part.
"""
from __future__ import annotations

import logging
import warnings
from pathlib import Path

import numpy as np
import torch
import xarray as xr

from deapull import dataset
from deapull.surrogate import store
from deapull.surrogate.data import load_setup
from deapull.surrogate.rollout import OutOfRangeWarning, rollout

log = logging.getLogger(__name__)
TIMING_REPEATS = 3


def load_models(model_dirs) -> list[tuple[Path, object, dict]]:
    """Load every model folder (each refused by name if unreadable) before any work."""
    return [(Path(d), *store.load(d)) for d in model_dirs]


def ladder_rows(models, data_dir: str | Path, setup: str, out_dir: str | Path) -> list[dict]:
    """One ladder row per loaded model: rollout on ``<data_dir>/<setup>.nc``, written to
    ``<out_dir>/cases/<case>/rollout.nc``.

    Parameters
    ----------
    models : list
        What :func:`load_models` returns.
    data_dir : str or pathlib.Path
        The sweep folder with ``<setup>.nc``.
    setup : str
        The ladder's setup (e.g. ``C3``).
    out_dir : str or pathlib.Path
        The ladder's output folder.

    Returns
    -------
    list of dict
        Rows with the ladder's keys (``case``, ``kind`` = ``surrogate``, ``status``,
        ``solve_s``, ``wall_s``, ``steps``, ``travel_mm``, ``dataset``...).
    """
    data = load_setup(Path(data_dir) / f"{setup}.nc")
    out_dir = Path(out_dir)
    rows, used = [], set()
    for path, model, meta in models:
        name = f"surrogate-{model.kind}"
        k = 2
        while name in used:
            name, k = f"surrogate-{model.kind}-{k}", k + 1
        used.add(name)
        phi = model.phi_of(data)       # the setup's own coin
        times = []
        with torch.inference_mode(), warnings.catch_warnings():
            warnings.simplefilter("ignore", OutOfRangeWarning)
            for _ in range(TIMING_REPEATS + 1):
                result = rollout(model, phi, data.states()[0], data.actions(), label=f"{name} on {setup}")
                times.append(result.wall_time_s)
        x = result.states[0, :, 0].double().cpu().numpy()
        columns = {"t": data.t, "x": x}
        if result.forces is not None:        # a black box predicts no force: its file has no Fy
            columns["Fy"] = np.concatenate([[data.Fy[0]], result.forces[0, :, 1].double().cpu().numpy()])
        case_dir = out_dir / "cases" / name
        dataset.write(rollout_dataset(columns, {"model": str(path), "kind": model.kind, "data": str(data.path)}),
                      case_dir / "rollout.nc")
        solve = min(times[1:])
        log.info("%s: %s rollout of %s in %.2f ms", name, result.engine, data.path, 1e3 * solve)
        rows.append({"case": name, "kind": "surrogate", "status": "ok", "reason": "",
                     "description": f"{model.kind} model {path} rolled out on {data.path.name} ({result.engine})",
                     "scene": "", "setup": setup, "overrides": [], "elements": f"surrogate {model.kind}",
                     "steps": data.n_steps, "solve_s": solve, "wall_s": solve, "travel_mm": float(abs(x).max()) * 1e3,
                     "protocol": f"actions of {data.path.name}",
                     "dataset": str((case_dir / "rollout.nc").relative_to(out_dir))})
    return rows


def rollout_dataset(columns: dict, attrs: dict) -> xr.Dataset:
    """A rollout as a dataset in the contract's names, units and long names, ``complete = 1``:
    ``t`` and ``x``, and ``Fy`` when the model predicts it (f = d∘m; not the black boxes).
    :func:`deapull.dataset.read` reads what it holds."""
    variables = {name: (dataset.DIM, np.asarray(values, dtype=float),
                        {"units": dataset.VARIABLES[name][0], "long_name": dataset.VARIABLES[name][1]})
                 for name, values in columns.items()}
    return xr.Dataset(variables, attrs={**attrs, "complete": 1})
