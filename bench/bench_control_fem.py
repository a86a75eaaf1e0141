"""FEM-in-the-loop benchmark (``make bench BENCH=control-fem``): one closed-loop episode of the MPC
on each FEM plant of ``--plant``, timed per part, in one run.

Per episode: ms per FEM step (``advance(V, 1 ms)`` at ``--fidelity``; make passes FIDELITY,
default resolved; serial), ms per MPC
plan (the compiled iLQR on f_a) and per inference update (none under ``make control PRESET=fem``'s
fixed prior), the closed-loop wall time of the
episode (placement, the start ramp and every step), and the ratio FEM step / MPC plan: how
much of the loop is the plant. Beside the paper's figures (``deapull.paper``: its MPC's time
per iteration and its ABAQUS run's time per ramp). Prints a table; ``--out``
keeps the harness's outputs (control.csv, traces, plots) and ``bench_control_fem.json``.

It takes ``deapull control``'s own flags and presets (``deapull control --options``); ``make bench
BENCH=control-fem`` passes it ``--preset fem``, ``make control PRESET=fem``'s own setting, so the two
cannot drift apart. ``FEM_PLANTS=C1,C3`` picks the setups. The policy must be ``mpc`` alone and every
plant a FEM plant: anything else exits 2 before any step.
"""
from __future__ import annotations

import dataclasses
import logging
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from deapull.errors import InputError  # noqa: E402
from deapull.io import markdown_table, write_json  # noqa: E402
from deapull.paper import ABAQUS_POINTS, ABAQUS_S, MPC_S_PER_ITERATION  # noqa: E402
from deapull.workflows import control  # noqa: E402


def config_of(argv):
    """``deapull control``'s :class:`ControlConfig` of ``argv``, checked to be the MPC alone on FEM
    plants (what this bench times); the progress bar off."""
    from deapull.workflows.cli import build_parser
    from deapull.workflows.cli_control import apply_preset, control_config
    args = build_parser().parse_args(["control", *argv])
    apply_preset(args, args.parser)
    config = control_config(args)
    if config.policies != ["mpc"]:
        raise InputError(f"--policy {','.join(config.policies)}: the bench times the MPC alone (--policy mpc)")
    others = [p.name for p in config.plants if p.kind != "fem"]
    if others:
        raise InputError(f"--plant {','.join(others)}: the bench times FEM plants only (fem:SETUP)")
    return dataclasses.replace(config, progress=False)


def main(argv=None) -> int:
    logging.basicConfig(level=logging.WARNING, format="%(name)s %(levelname)s: %(message)s")
    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        config = config_of(argv)
    except InputError as e:
        print(f"bench_control_fem: error: {e}", file=sys.stderr)
        return 2
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
    write_json(config.out / "bench_control_fem.json", {"rows": table, "noise_std_m": config.noises,
                                                       "setting": argv}, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
