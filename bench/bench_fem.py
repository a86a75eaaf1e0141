"""FEM benchmark (``make bench-fem``): one setup on one core, its accuracy against the
committed contact-ladder reference, and the 8-setup sweep under ``mpirun -n 2``, beside the paper's
ABAQUS time (``deapull.paper``).

Measured in this run, on C3: the scene file as written (the fast preview of ``make demo``),
the ``resolved`` fidelity (the datasets' default: the resolved contact patch), each with its wall
time and Newton iterations, and the old default (full model, 16 x 2, MUMPS) as the baseline of
the speed ratio, and ``resolved`` with the contact integral over the whole underside
(``contact.reach_m = 0``) as the baseline of the reach's; then the 8-setup sweep at ``--fidelity`` (default resolved). The
accuracy is against the committed reference of ``deapull fem-study --study
reference`` (``bench/reference/``: the finest half-model run's x(t) and the Richardson
travel with its error bound over the tip zone and the penalty, the directions that ladder
refines; ``beyond_the_ladder.json`` beside it holds the measured runs refined in the layers
and the underside, which move the travel 5-9 %, and the bench prints them under the ladder:
the reference is not converged beyond its ladder); ``--reference DIR`` points at a fresh one. Nothing here is
asserted: it prints, and writes ``bench_fem.json``.
"""
from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from deapull import dataset
from deapull.io import write_json
from deapull.paper import ABAQUS_POINTS, ABAQUS_S
from deapull.workflows.fem_study import OLD_DEFAULT, ladder_gap, ladder_table, load_reference, mpirun_env

PAPER_ABAQUS_S = ABAQUS_S          # paper: 1 s / ABAQUS_POINTS points per setup
TARGET_S, TARGET_TRAVEL_ERR, TARGET_MAE, TARGET_SWEEP_S = 13.0, 0.02, 0.01, 60.0   # issue 12's goals
REFERENCE = Path(__file__).parent / "reference"
#: resolved with the contact integral over the whole underside (contact.reach_m = 0): the baseline of the
#: reach's speed-up (the same solution to the bit, docs/fem_accuracy.md)
REACH_BASELINE = "resolved, whole underside (baseline)"


def run(cmd, env=None) -> float:
    start = time.perf_counter()
    subprocess.run(cmd, check=True, env=env)
    return time.perf_counter() - start


def solve(out: Path, overrides=(), fidelity: str = "") -> dataset.Run:
    cmd = [sys.executable, "-m", "deapull.workflows", "solve", "--scene", "coin_pull", "--setup", "C3", "--out", str(out)]
    cmd += ["--fidelity", fidelity] if fidelity else []
    for o in overrides:
        cmd += ["--set", o]
    run(cmd)
    return dataset.read(out / "C3.nc", ("t", "x", "newton_iterations"))


def accuracy(r: dataset.Run, ref: dict, fine: dataset.Run) -> tuple[float, float]:
    """(travel error, x(t) MAE), both relative to the reference travel."""
    travel_ref = ref["travel_ref_m"]
    x = r.columns["x"]
    t_ref = fine.columns["t"]
    mae = float(np.mean(np.abs(np.interp(t_ref, r.columns["t"], x) - fine.columns["x"])))
    return float(np.max(np.abs(x))) / travel_ref - 1, mae / travel_ref


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/bench_fem")
    ap.add_argument("--np", type=int, default=2, help="MPI ranks for the sweep")
    ap.add_argument("--reference", default=str(REFERENCE),
                    help="folder with reference.json and C3_reference.nc (deapull fem-study --study reference)")
    ap.add_argument("--fidelity", default="resolved",
                    help="the sweep's fidelity (a [fidelities.NAME] of coin_pull; '' = the file as written; "
                         "default resolved, as make sweep)")
    ap.add_argument("--skip-sweep", action="store_true")
    ap.add_argument("--skip-baseline", action="store_true")
    args = ap.parse_args(argv)
    out, refdir = Path(args.out), Path(args.reference)
    ref = load_reference(refdir)
    fine = dataset.read(refdir / "C3_reference.nc", ("t", "x"))

    res = {}
    cases = [("fast (scene file)", "fast", (), ""), ("resolved (datasets)", "resolved", (), "resolved")]
    cases += [] if args.skip_baseline else [("old default (baseline)", "old", OLD_DEFAULT, ""),
                                            (REACH_BASELINE, "resolved_reach0", ("contact.reach_m=0",), "resolved")]
    for label, folder, overrides, fidelity in cases:
        r = solve(out / folder, overrides, fidelity)
        err, mae = accuracy(r, ref, fine)
        res[label] = {"wall_s": r.number("wall_time_total_s"), "points": len(r.columns["t"]),
                      "dofs": int(r.attrs["mesh_dofs"]), "newton_its": int(np.sum(r.columns["newton_iterations"])),
                      "travel_mm": 1e3 * float(np.max(np.abs(r.columns["x"]))), "travel_err": err, "x_mae": mae,
                      "slip_rate_reg_m_s": r.number("contact_slip_rate_reg_m_s")}
    if not args.skip_sweep:
        env = mpirun_env()
        sweep_dir = out / "sweep"
        if sweep_dir.exists():            # a timed sweep from scratch: no dataset, no stored result
            shutil.rmtree(sweep_dir)
        fid = ["--fidelity", args.fidelity] if args.fidelity else []
        res["sweep"] = {"wall_s": run(["mpirun", "-n", str(args.np), sys.executable, "-m", "deapull.workflows",
                                       "sweep", "--scene", "coin_pull", *fid, "--out", str(sweep_dir)], env=env),
                        "np": args.np, "fidelity": args.fidelity or "the scene file"}
    res["reference"] = ref
    write_json(out / "bench_fem.json", res, indent=2)

    bound, gap = ref.get("error_bound_rel"), ladder_gap(ref)
    own = "± %.2f %%" % (100 * bound) if bound is not None else "unknown (not converged)"
    if bound is not None and gap is not None:
        own += (f" over the tip zone and the penalty only; refining the layers and the underside moves the travel "
                f"{100 * gap['least_rel']:+.1f} % or more (below), so the errors against it are distances to a mesh "
                "that is not converged")
    print(f"\nFEM benchmark: coin_pull C3, 1 s ramp 0-400 V, one core; reference: {ref['label']}, travel "
          f"{1e3 * ref['travel_ref_m']:.4f} mm, its own error {own}")
    print(ladder_table(ref) + "\n")
    head = f"{'':36s} {'wall s':>8s} {'vs ABAQUS':>10s} {'points':>7s} {'dofs':>6s} {'Newton':>7s} " \
           f"{'travel mm':>10s} {'travel err':>11s} {'x(t) MAE':>9s}"
    print(head)
    for label, r in ((k, v) for k, v in res.items() if k not in ("sweep", "reference")):
        print(f"{label:36s} {r['wall_s']:8.1f} {PAPER_ABAQUS_S / r['wall_s']:9.1f}x {r['points']:7d} {r['dofs']:6d} "
              f"{r['newton_its']:7d} {r['travel_mm']:10.4f} {100 * r['travel_err']:+10.2f}% {100 * r['x_mae']:8.2f}%")
    print(f"{'paper (ABAQUS)':36s} {PAPER_ABAQUS_S:8.1f} {'1.0x':>10s} {ABAQUS_POINTS:7d}")
    print(f"{'goal':36s} {TARGET_S:8.1f} {'':>10s} {'':>7s} {'':>6s} {'':>7s} {'':>10s} "
          f"{'≤ ' + str(100 * TARGET_TRAVEL_ERR) + '%':>11s} {'≤ ' + str(100 * TARGET_MAE) + '%':>9s}")
    fast, resolved = res["fast (scene file)"], res["resolved (datasets)"]
    print(f"resolved costs {resolved['wall_s'] / fast['wall_s']:.1f}x the fast preview, same run")
    if "old default (baseline)" in res:
        old = res["old default (baseline)"]
        print(f"speed-up over the old default, same run: fast {old['wall_s'] / fast['wall_s']:.2f}x, "
              f"resolved {old['wall_s'] / resolved['wall_s']:.2f}x")
    if REACH_BASELINE in res:
        whole = res[REACH_BASELINE]
        print(f"contact.reach_m (5 mm) against the whole underside, resolved, same run: "
              f"{whole['wall_s'] / resolved['wall_s']:.2f}x, travel {resolved['travel_mm']:.6f} against "
              f"{whole['travel_mm']:.6f} mm")
    if "sweep" in res:
        s = res["sweep"]
        print(f"8-setup sweep at {s['fidelity']}, mpirun -n {s['np']}: {s['wall_s']:.1f} s (goal ≤ {TARGET_SWEEP_S:.0f} s; "
              f"ABAQUS 8 x {PAPER_ABAQUS_S:g} s = {8 * PAPER_ABAQUS_S:.0f} s, "
              f"ratio {8 * PAPER_ABAQUS_S / s['wall_s']:.1f}x)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
