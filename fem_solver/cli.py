"""Sub-commands of the FEM stage: ``solve`` and ``sweep`` (dolfinx is imported lazily)."""
from __future__ import annotations

import sys


def cmd_solve(args) -> int:
    from mpi4py import MPI

    from fem_solver.run import solve_scene
    from fem_solver.stepping import SolveFailed
    from workflows.cli import load_scene
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
    from mpi4py import MPI

    from fem_solver.sweep import format_table, sweep
    setups = [s.strip() for s in args.setups.split(",") if s.strip()] if args.setups else None
    rows = sweep(args.scene, setups, args.out, MPI.COMM_WORLD, args.ranks_per_setup, args.overrides)
    if MPI.COMM_WORLD.rank == 0:
        print(format_table(rows))
    return 0 if all(r.status == "ok" for r in rows) else 1


def register(sub) -> None:
    from workflows.cli import add_scene_args
    p = sub.add_parser("solve", help="solve one scene / setup with dolfinx and write its dataset")
    add_scene_args(p)
    p.add_argument("--out", required=True, help="output folder (dataset <setup>.nc, meshes/)")
    p.add_argument("--fields-every", type=int, default=0, metavar="N",
                   help="also write displacement fields (XDMF) every N steps")
    p.set_defaults(func=cmd_solve)

    p = sub.add_parser("sweep", help="solve every setup of a scene (run under mpirun -n N)")
    p.add_argument("--scene", default="coin_pull", help="scene with setups (default coin_pull)")
    p.add_argument("--setups", default="", help="comma-separated setups (default: all)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--ranks-per-setup", type=int, default=1, help="ranks sharing one setup's mesh")
    p.set_defaults(func=cmd_sweep)
