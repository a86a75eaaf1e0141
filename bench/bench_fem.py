"""FEM benchmark (``make bench BENCH=fem``): coin_pull C3 on one core at the data fidelity (the scene file
as written) and at ``preview``, their x(0.95 s) against the committed contact reference
(``bench/reference/contact_reference.json``, ``make fem-study``), then the 8-setup sweep under
``mpirun -n NP``, beside the paper's ABAQUS time and the moonshot of a tenth of it.

Nothing here is asserted: it prints, and writes ``bench_fem.json``.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from deapull import dataset
from deapull.fem_solver.compat import FORM_CFLAGS_ENV
from deapull.io import write_json
from deapull.paper import ABAQUS_POINTS, ABAQUS_S

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = ROOT / "bench" / "reference" / "contact_reference.json"
#: the goals beside the paper's 130 s: C3 on one core, the 8-setup sweep on 2 ranks, and the moonshot
GOAL_C3_S, GOAL_SWEEP_S, MOONSHOT_S = 60.0, 240.0, ABAQUS_S / 10
#: (label, folder, --fidelity, --set overrides, the forms' C flags or None: compat.FORM_CFLAGS); the
#: baseline is the data fidelity on the solver path before the last speed-ups (the linear predictor, the
#: line search's solves at the full-step solves' Jacobian reuse 0.6, the coin-DEA iteration converged to
#: 0.1 nm, Newton to a residual of 1e-8 N, the forms compiled at dolfinx's own flags), timed in the same run
BASELINE = ("solver.predictor='linear'", "solver.line_search_reuse_ratio=0.6", "solver.coupling_tol_m=1e-10",
            "solver.newton_atol=1e-8")
BASELINE_CFLAGS = "-O2 -g0"
CASES = (("data fidelity (scene file)", "data", "", (), None),
         ("baseline: linear predictor, line-search reuse 0.6, coupling 0.1 nm, Newton 1e-8 N, forms -O2",
          "baseline", "", BASELINE, BASELINE_CFLAGS),
         ("preview", "preview", "preview", (), None))


def run(cmd, env=None) -> float:
    start = time.perf_counter()
    subprocess.run(cmd, check=True, env=env)
    return time.perf_counter() - start


def mpirun_env() -> dict:
    return dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
                OMPI_MCA_rmaps_base_oversubscribe="1")


def solve(out: Path, fidelity: str, overrides=(), cflags: str | None = None) -> dataset.Run:
    if out.exists():     # from scratch: no placement kept from an earlier run (fem_solver.simulation.PlacementCache)
        shutil.rmtree(out)
    cmd = [sys.executable, "-m", "deapull.workflows", "solve", "--scene", "coin_pull", "--setup", "C3", "--out", str(out)]
    env = dict(os.environ, **{FORM_CFLAGS_ENV: cflags}) if cflags else None
    run(cmd + (["--fidelity", fidelity] if fidelity else []) + [a for o in overrides for a in ("--set", o)], env=env)
    return dataset.read(out / "C3.nc", ("t", "x", "newton_iterations", "n_contact"))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/bench_fem")
    ap.add_argument("--np", type=int, default=2, help="MPI ranks for the sweep")
    ap.add_argument("--reference", default=str(REFERENCE), help="the contact study's JSON (make fem-study)")
    ap.add_argument("--skip-sweep", action="store_true")
    args = ap.parse_args(argv)
    out, ref_path = Path(args.out), Path(args.reference)
    ref = json.loads(ref_path.read_text()) if ref_path.is_file() else {}
    t_ref, x_ref = ref.get("time_s", 0.95), ref.get("reference_x_at_t_mm")
    runs, wall = {}, {}
    for label, folder, fidelity, overrides, cflags in CASES:
        r = solve(out / folder, fidelity, overrides, cflags)
        wall[folder] = r.number("wall_time_total_s")
        c = r.columns
        x_t = 1e3 * float(np.interp(t_ref, c["t"], c["x"]))
        touching = c["n_contact"][c["n_contact"] > 0]
        runs[label] = {"wall_s": r.number("wall_time_total_s"), "points": len(c["t"]), "dofs": int(r.attrs["mesh_dofs"]),
                      "newton_its": int(np.sum(c["newton_iterations"])), "x_at_t_mm": x_t,
                      "travel_mm": 1e3 * float(np.max(np.abs(c["x"]))),
                      "error_percent": 100 * (x_t / x_ref - 1) if x_ref else None,
                      "min_contact_points": int(touching.min()) if touching.size else 0}
    res = {"runs": runs}
    if not args.skip_sweep:
        sweep_dir = out / "sweep"
        if sweep_dir.exists():            # a timed sweep from scratch: no dataset, no stored result
            shutil.rmtree(sweep_dir)
        res["sweep"] = {"wall_s": run(["mpirun", "-n", str(args.np), sys.executable, "-m", "deapull.workflows",
                                       "sweep", "--scene", "coin_pull", "--out", str(sweep_dir)], env=mpirun_env()),
                        "np": args.np}
    shown = ref_path.resolve().relative_to(ROOT) if ref_path.resolve().is_relative_to(ROOT) else ref_path
    res["reference"] = {"file": str(shown), "x_at_t_mm": x_ref, "time_s": t_ref,
                        "bound_percent": ref.get("bound_percent")}
    res["goals"] = {"c3_one_core_s": GOAL_C3_S, "sweep_s": GOAL_SWEEP_S, "moonshot_s": MOONSHOT_S, "abaqus_s": ABAQUS_S}
    write_json(out / "bench_fem.json", res, indent=2)

    print(f"\nFEM benchmark: coin_pull C3, 0-400 V in 1 s, one core; reference x({t_ref:g} s) = "
          + (f"{x_ref:.4f} mm ± {ref['bound_percent']:.2f} %" if x_ref else "none (make fem-study)"))
    print(f"{'':30s} {'wall s':>8s} {'vs ABAQUS':>10s} {'points':>7s} {'dofs':>6s} {'Newton':>7s} "
          f"{'x(t) mm':>9s} {'error':>8s} {'contact pts':>11s}")
    for label, r in runs.items():
        err = f"{r['error_percent']:+7.2f}%" if r["error_percent"] is not None else f"{'–':>8s}"
        print(f"{label:30s} {r['wall_s']:8.1f} {ABAQUS_S / r['wall_s']:9.2f}x {r['points']:7d} {r['dofs']:6d} "
              f"{r['newton_its']:7d} {r['x_at_t_mm']:9.4f} {err} {r['min_contact_points']:11d}")
    print(f"{'speed-up over the baseline':30s} {wall['baseline'] / wall['data']:8.2f}x")
    print(f"{'paper (ABAQUS)':30s} {ABAQUS_S:8.1f} {'1.00x':>10s} {ABAQUS_POINTS:7d}")
    print(f"{'goal / moonshot':30s} {GOAL_C3_S:8.1f} / {MOONSHOT_S:.0f} s")
    if "sweep" in res:
        s = res["sweep"]
        print(f"8-setup sweep, mpirun -n {s['np']}: {s['wall_s']:.1f} s (goal <= {GOAL_SWEEP_S:.0f} s; "
              f"ABAQUS 8 x {ABAQUS_S:g} s = {8 * ABAQUS_S:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
