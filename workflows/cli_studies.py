"""Sub-commands of the FEM studies: ``fidelity``, ``stability`` and ``fem-study`` (dolfinx is imported lazily).

Both run under ``mpirun -n N`` like the sweep (cases over rank groups, one rank per case by
default), resume after an interruption, and print their table on rank 0.
"""
from __future__ import annotations

from pathlib import Path

from deapull import scene as scenes
from deapull.workflows import convergence
from deapull.workflows.args import add_scene_args, names, overrides_of
from deapull.workflows.fidelity import run_ladder, summary_table as fidelity_table
from deapull.workflows.stability import run_stability, summary_table as stability_table


def cmd_fidelity(args) -> int:
    from mpi4py import MPI  # lazy: importing mpi4py initialises MPI; the CLI starts without it
    extra = None
    if args.surrogate:   # models and their dataset are checked before any FEM work
        from deapull.surrogate.data import load_setup  # lazy: torch loads only with --surrogate
        from deapull.workflows import ladder  # lazy: torch
        setup = scenes.load(args.scene, setup=args.setup, overrides=overrides_of(args)).setup
        models = ladder.load_models(args.surrogate)
        load_setup(Path(args.surrogate_data) / f"{setup}.nc")

        def surrogate_rows(setup_name):
            return ladder.ladder_rows(models, args.surrogate_data, setup_name, args.out)
        extra = surrogate_rows
    rows = run_ladder(args.scene, args.setup, args.out, MPI.COMM_WORLD, args.rungs, args.overrides,
                      names(args.only), args.ranks_per_case, extra_rows=extra, fidelity=args.fidelity,
                      study=args.study)
    if MPI.COMM_WORLD.rank != 0:
        return 0
    print(fidelity_table(rows))
    print(f"wrote {args.out}/fidelity.csv, fidelity.md, fidelity_pareto.png")
    reference = next(r for r in rows if r.get("is_reference"))
    return 0 if reference["status"] == "ok" else 1


def cmd_stability(args) -> int:
    from mpi4py import MPI  # lazy: importing mpi4py initialises MPI; the CLI starts without it
    rows = run_stability(args.out, MPI.COMM_WORLD, args.protocol, names(args.cases), args.overrides,
                         args.ranks_per_case, args.fidelity, args.study)
    if MPI.COMM_WORLD.rank != 0:
        return 0
    print(stability_table(rows))
    print(f"wrote {args.out}/stability.csv, stability.md")
    return 1 if any(r["status"] == "error" for r in rows) else 0


def cmd_fem_study(args) -> int:
    from mpi4py import MPI  # lazy: importing mpi4py initialises MPI; the CLI starts without it
    convergence.load_study(args.study)          # a bad study file: InputError before any run
    result = convergence.run_study(args.study, Path(args.out), MPI.COMM_WORLD, args.ranks_per_case,
                                   Path(args.publish) if args.publish else None, names(args.only),
                                   Path(args.reuse) if args.reuse else None)
    if MPI.COMM_WORLD.rank != 0:
        return 0
    print("\n".join(convergence.report_lines(result)))
    if result["not_run"]:
        print("not run yet: " + ", ".join(result["not_run"]))
    if result["failed"]:
        print("failed: " + "; ".join(f"{k}: {v}" for k, v in result["failed"].items()))
    return 1 if result["failed"] else 0


def _common(p) -> None:
    p.add_argument("--out", required=True, help="output folder (cases/, CSV, Markdown)")
    p.add_argument("--ranks-per-case", type=int, default=1, help="ranks sharing one case's mesh (default 1)")


def register(sub) -> None:
    p = sub.add_parser("fidelity", help="error against run time: ladder of meshes, elements and steps "
                                        "(run under mpirun -n N; resumes)")
    add_scene_args(p, scene_default="coin_pull",
                   set_help="override one scene key in every rung (validated like the file); repeatable")
    p.add_argument("--study", default="fidelity", help="the ladder: a study of studies/ by name, or a TOML file "
                                                       "(default fidelity)")
    p.add_argument("--rungs", default="quick", choices=("quick", "full"),
                   help="quick: base step end/100 plus the shipped step; full: the scene's steps (default quick)")
    p.add_argument("--only", default="", help="comma-separated rung names (default: all; the reference is "
                                              "always run)")
    p.add_argument("--surrogate", action="append", default=[], metavar="MODEL_DIR",
                   help="also place a trained surrogate (a folder from `deapull train`/`experiments`) on the "
                        "ladder, rolled out over the sweep dataset of the setup; repeatable")
    p.add_argument("--surrogate-data", default="data", help="sweep folder with <setup>.nc for --surrogate "
                                                            "(default data)")
    _common(p)
    p.set_defaults(func=cmd_fidelity)

    p = sub.add_parser("stability", help="stiff and extreme cases, each a row: converged or why not "
                                         "(run under mpirun -n N; resumes)")
    p.add_argument("--study", default="stability", help="the cases: a study of studies/ by name, or a TOML file "
                                                        "(default stability)")
    p.add_argument("--cases", default="", help="comma-separated case names (default: all)")
    # its cases are of several scenes: --fidelity applies to each case whose scene defines it
    # (workflows/stability.py); free_bending's pull-in runs as written and its row says so
    add_scene_args(p, scene=False, setup=False,
                   set_help="override one scene key in every case (validated like the file); repeatable")
    p.add_argument("--protocol", default="quick", choices=("quick", "full"),
                   help="quick: 1 s ramp with base step 0.01 s; full: the scene's steps (default quick)")
    _common(p)
    p.set_defaults(func=cmd_stability)

    p = sub.add_parser("fem-study", help="FEM accuracy studies of coin_pull C3: the contact-ladder reference's "
                                         "convergence table and bound, and each study's cases against it "
                                         "(default: the shipped default and its contact rule doubled; resumes)")
    p.add_argument("--study", default="contact_reference",
                   help="a study of studies/ by name, or a TOML file (default contact_reference: the contact "
                        "ladders' orders and bound, and the data fidelity against their Richardson value)")
    p.add_argument("--publish", default="", help="also write the study's JSON into this folder (bench/reference)")
    p.add_argument("--only", default="", help="comma-separated cases to solve now (default: all); the summary "
                                              "takes every case solved so far")
    p.add_argument("--reuse", default="", help="a published result of the study (bench/reference/<study>.json): "
                                               "the cases not solved in --out are taken from it where their "
                                               "overrides are unchanged")
    _common(p)
    p.set_defaults(func=cmd_fem_study)
