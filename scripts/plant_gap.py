"""How far each MPC model f_a is from the control plants f_s,1 / f_s,2 under the same push.

A diagnostic for docs/control.md (twentieth session) and docs/surrogate.md (f-patch-lag): every
model is rolled out from rest with the true phi of C1 (then C2), in 1 ms steps (the control
plants' step), with V rising by ``--volts-per-step`` to 400 V and then held for 200 steps. It
prints the plant's travel at 400 V and after the hold, and each f_a's difference from it in %.
0.4 V per step is the FEM ramp's rate; 5 V per step is the MPC's full push.

With ``--fem-runs DIR`` the push is instead the voltage of the FEM runs ``DIR/C1_*.nc`` and
``DIR/C2_*.nc`` (e.g. the 80 ms pushes of ``make push-ramps``), sampled every 1 ms, and every model,
the plants included, is compared with the FEM's own travel at the ramp's top and at the end.

::

    .venv/bin/python scripts/plant_gap.py out/models/fa out/s20/fa_lag [--volts-per-step 5]
        [--data data] [--plants out/models] [--fem-runs data/push]

Not part of any make target.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

HOLD_STEPS = 200


def travel(model, phi, voltages) -> np.ndarray:
    """x (m) after each step of ``voltages`` of ``model`` as a plant, from rest."""
    from deapull.control.plants import SurrogatePlant   # lazy: torch
    plant = SurrogatePlant(model, phi)
    plant.reset()
    return np.array([plant.step(V)[0] for V in voltages])


def gaps(folders, data, voltages, x_ref, top: int, end: str) -> list[str]:
    """Each model's travel against ``x_ref`` at step ``top`` and at the last step, in %, with the
    coin of ``data`` (a model is named by its folder and the folder above it)."""
    from deapull.surrogate import store                 # lazy: torch
    cells = []
    for folder in folders:
        model, _ = store.load(folder)
        x = travel(model, model.phi_of(data), voltages)
        cells.append(f"{folder.parent.name}/{folder.name}: {100 * (x[top] / x_ref[top] - 1):+.2f} % "
                     f"({100 * (x[-1] / x_ref[-1] - 1):+.2f} % {end})")
    return cells


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("models", nargs="+", type=Path, help="f_a folders written by `deapull train`")
    p.add_argument("--volts-per-step", type=float, default=5.0)
    p.add_argument("--data", type=Path, default=Path("data"), help="folder with C1.nc, C2.nc (their phi)")
    p.add_argument("--plants", type=Path, default=Path("out/models"), help="folder with fs1/, fs2/ (make control)")
    p.add_argument("--fem-runs", type=Path, default=None,
                   help="folder with FEM runs C1_*.nc, C2_*.nc: their voltage is the push, their travel the reference")
    args = p.parse_args(argv)
    if args.fem_runs is not None:
        runs = {n: sorted(args.fem_runs.glob(f"C{n}_*.nc")) for n in (1, 2)}
        if not all(runs.values()):
            p.error(f"--fem-runs {args.fem_runs}: needs a run C1_<name>.nc and C2_<name>.nc (found "
                    f"{', '.join(str(f) for fs in runs.values() for f in fs) or 'none'})")
    if not 0 < args.volts_per_step <= 400:
        p.error(f"--volts-per-step {args.volts_per_step!r}: must be in (0, 400]")
    folders = [*args.models, args.plants / "fs1", args.plants / "fs2"]
    missing = [str(f) for f in folders if not (f / "model.json").is_file()]
    if missing:
        p.error(f"no model.json (a folder written by `deapull train`) in {', '.join(missing)}")
    from deapull.surrogate import store                 # lazy: torch
    from deapull.surrogate.data import load_setup
    if args.fem_runs is not None:
        for n in (1, 2):
            data = load_setup(args.data / f"C{n}.nc")
            for run in runs[n]:
                fem = load_setup(run)
                steps = np.arange(1, int(round(fem.t[-1] / 1e-3)) + 1) * 1e-3
                voltages, x_fem = np.interp(steps, fem.t, fem.V), np.interp(steps, fem.t, fem.x)
                top = int(np.argmax(voltages >= voltages.max() - 1e-6))
                line = [f"{run.stem}: FEM {abs(x_fem[top]) * 1e3:.4f} mm at {voltages[top]:.0f} V "
                        f"(t = {steps[top] * 1e3:.0f} ms), {abs(x_fem[-1]) * 1e3:.4f} mm at the end"]
                line += gaps([args.plants / f"fs{n}", *args.models], data, voltages, x_fem, top, "at the end")
                print(" | ".join(line))
        return 0
    ramp = list(np.arange(args.volts_per_step, 400.0 + 1e-9, args.volts_per_step))
    voltages, top = ramp + [400.0] * HOLD_STEPS, len(ramp) - 1
    for n in (1, 2):
        data = load_setup(args.data / f"C{n}.nc")
        plant, _ = store.load(args.plants / f"fs{n}")
        x_plant = travel(plant, plant.phi_of(data), voltages)
        line = [f"C{n}: plant {abs(x_plant[top]) * 1e3:.4f} mm at 400 V, {abs(x_plant[-1]) * 1e3:.4f} mm held"]
        line += gaps(args.models, data, voltages, x_plant, top, "held")
        print(" | ".join(line))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
