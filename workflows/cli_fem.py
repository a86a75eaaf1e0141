"""``deapull solve`` and ``deapull sweep`` (dolfinx is imported lazily)."""
from __future__ import annotations

import sys

from deapull import scene as scenes
from deapull.workflows.args import add_scene_args, load_scene, names
from deapull.workflows.sweep import PROTOCOL_SETS, format_table, sweep


def cmd_solve(args) -> int:
    from mpi4py import MPI  # lazy: importing mpi4py initialises MPI

    from deapull.fem_solver.run import solve_scene  # lazy: dolfinx
    from deapull.fem_solver.stepping import SolveFailed  # lazy: dolfinx
    scene = load_scene(args)
    try:
        path = solve_scene(scene, args.out, MPI.COMM_WORLD, fields_every=args.fields_every)
    except SolveFailed as err:
        if MPI.COMM_WORLD.rank == 0:
            print(f"deapull solve: {err} (no dataset written)", file=sys.stderr)
        return 1
    if MPI.COMM_WORLD.rank == 0:
        print(f"wrote {path}")
    return 0


def cmd_sweep(args) -> int:
    from mpi4py import MPI  # lazy: importing mpi4py initialises MPI; the CLI starts without it

    setups = names(args.setups)
    # the fidelity before the protocol set's overrides (a set may carry its own mesh), --set last
    rows = sweep(args.scene, setups, args.out, MPI.COMM_WORLD, args.ranks_per_setup, tuple(args.overrides),
                 args.protocols, scenes.fidelity_overrides(args.scene, args.fidelity))
    if MPI.COMM_WORLD.rank == 0:
        print(format_table(rows))
    return 0 if all(r["status"] == "ok" for r in rows) else 1


def register(sub) -> None:
    p = sub.add_parser("solve", help="solve one scene / setup with dolfinx and write its dataset")
    add_scene_args(p)
    p.add_argument("--out", required=True, help="output folder (dataset <setup>.nc, meshes/)")
    p.add_argument("--fields-every", type=int, default=0, metavar="N",
                   help="also write displacement fields (XDMF) every N steps")
    p.set_defaults(func=cmd_solve)

    p = sub.add_parser("sweep", help="solve every setup of a scene (run under mpirun -n N)")
    add_scene_args(p, setup=False, scene_default="coin_pull")
    p.add_argument("--setups", default="", help="comma-separated setups (default: all)")
    p.add_argument("--protocols", default="scene", choices=tuple(PROTOCOL_SETS),
                   help="scene: the scene's own protocol -> <setup>.nc (default); excitation: ramp-hold-ramp, "
                        "triangle, release and 3 seeded random inputs -> <setup>_<protocol>.nc; push: the ramp in "
                        "80 ms (the MPC's 5 V per 1 ms step), then held -> <setup>_fast.nc")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--ranks-per-setup", type=int, default=1, help="ranks sharing one setup's mesh")
    p.set_defaults(func=cmd_sweep)
