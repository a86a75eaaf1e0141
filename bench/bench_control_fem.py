"""FEM-in-the-loop benchmark (``make bench-control-fem``): one closed-loop episode of the MPC
on the FEM plant of each ``--plants`` setup, timed per part, in one run.

Per episode: ms per FEM step (``advance(V, 1 ms)`` at ``--fidelity``, default resolved, serial), ms per MPC
plan (the compiled iLQR on f_a) and per inference update (none under ``make control-fem``'s
fixed prior), the closed-loop wall time of the
episode (placement, the start ramp and every step), and the ratio FEM step / MPC plan: how
much of the loop is the plant. Beside the paper's figures (``deapull.paper``: its MPC's time
per iteration and its ABAQUS run's time per ramp). Prints a table; ``--out``
keeps the harness's outputs (control.csv, traces, plots) and ``bench_control_fem.json``.

The defaults are ``make control-fem``'s setting (the f-memory f_a at the coin prior's median φ,
0.4 V per step tapered to 0.1 V within 0.1 mm, a stand-off of 2 stds, the bias filter's
innovation check over 25 steps, 4,000 steps); ``--mpc-model out/models/fa --infer --standoff 0
--innovation-window 0 --max-steps 3000`` times ``make control-fem-infer``'s.
"""
from __future__ import annotations

import argparse
import logging
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from deapull import scene as scenes  # noqa: E402
from deapull.io import markdown_table, write_json  # noqa: E402
from deapull.paper import ABAQUS_POINTS, ABAQUS_S, MPC_S_PER_ITERATION  # noqa: E402
from deapull.workflows import control  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--plants", default="C3", help="setups of the FEM plant, comma-separated (default C3)")
    ap.add_argument("--noise", type=float, default=1e-4, help="observation noise std (m; default 1e-4)")
    ap.add_argument("--mpc-model", default="out/models/fa_mem",
                    help="f_a (default out/models/fa_mem, the f-memory f_a of make control-fem)")
    ap.add_argument("--data", default="data")
    ap.add_argument("--hold", type=int, default=100)
    ap.add_argument("--max-steps", type=int, default=4000)
    ap.add_argument("--max-rate", type=float, default=0.4, help="the MPC's |dV| per step (V; as make control-fem)")
    ap.add_argument("--approach-mm", type=float, default=0.1, help="the MPC's approach limit (mm; as make control-fem)")
    ap.add_argument("--creep", type=float, default=0.1, help="the MPC's smallest |dV| per step (V; as make control-fem)")
    ap.add_argument("--standoff", type=float, default=2.0, help="the MPC's stand-off in stds (as make control-fem)")
    ap.add_argument("--innovation-window", type=int, default=25,
                    help="the bias filter's innovation check, in steps (as make control-fem; 0 = off)")
    ap.add_argument("--infer", action="store_true",
                    help="infer φ online (make control-fem-infer; needs an f_a that can: f-coulomb); default: plan "
                         "at the coin prior's median, as make control-fem")
    ap.add_argument("--fidelity", default="resolved",
                    help="the FEM plant's fidelity (a [fidelities.NAME] of coin_pull; '' = the file as written; "
                         "default resolved, as the datasets)")
    ap.add_argument("--out", default="out/bench_control_fem")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(name)s %(levelname)s: %(message)s")
    config = control.ControlConfig(
        policies=["mpc"], plants=control.parse_plants(",".join(f"fem:{s}" for s in control.parse_list(args.plants,
                                                                                                     "--plants"))),
        noises=[args.noise], out=Path(args.out), episodes=1, hold_steps=args.hold, max_steps=args.max_steps,
        data=Path(args.data), mpc_model=args.mpc_model, phi_prior="coins", mpc_approach_m=1e-3 * args.approach_mm,
        mpc_standoff=args.standoff, mpc_innovation_window=args.innovation_window, mpc_no_infer=not args.infer,
        mpc_max_rate_V=args.max_rate, mpc_creep_V=args.creep, progress=False,
        overrides=list(scenes.fidelity_overrides("coin_pull", args.fidelity)), unreachable="report")
    rows = [e.row for e in control.run(config)]
    table = []
    for r in rows:
        fem, plan, infer = r["plant_ms_per_step"], r["solve_ms_per_iteration"], r["inference_ms_per_iteration"] or 0.0
        table.append({"plant": r["plant"], "steps": r["steps_run"], "fem_ms": fem, "plan_ms": plan, "infer_ms": infer,
                      "ratio": fem / plan if plan else float("nan"), "wall_s": r["episode_wall_s"],
                      "reached": f"{int(r['iterations_to_target']):d}" if r["reached"] else "–",
                      "settled": "yes" if r["settled"] else "no", "overshoot_mm": 1e3 * r["overshoot_m"]})
    print(markdown_table(table, [
        ("plant", "plant", "s"), ("steps", "steps", "d"), ("FEM ms / step", "fem_ms", ".1f"),
        ("MPC ms / plan", "plan_ms", ".2f"), ("inference ms / step", "infer_ms", ".2f"),
        ("FEM step / MPC plan", "ratio", ".0f"), ("episode wall time (s)", "wall_s", ".1f"),
        ("iterations to target", "reached", "s"), ("settled", "settled", "s"), ("overshoot (mm)", "overshoot_mm", ".3f")]))
    print(f"paper: MPC {MPC_S_PER_ITERATION * 1e3:.0f} ms per iteration (mpc.pytorch); ABAQUS {ABAQUS_S:g} s per "
          f"1 s ramp of {ABAQUS_POINTS} points ({1e3 * ABAQUS_S / ABAQUS_POINTS:.0f} ms per point)")
    if rows:
        print(f"median FEM step {statistics.median(t['fem_ms'] for t in table):.1f} ms, "
              f"median MPC plan {statistics.median(t['plan_ms'] for t in table):.2f} ms")
    write_json(Path(args.out) / "bench_control_fem.json", {"rows": table, "noise_std_m": args.noise,
                                                           "setting": vars(args)}, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
