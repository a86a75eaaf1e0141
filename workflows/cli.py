"""``deapull``: the verbs of the pipeline.

Every sub-command validates its input before any expensive work; bad input
(:class:`workflows.errors.InputError`) prints one clear line and exits with status 2.
Under MPI only rank 0 prints.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys

from workflows import scene as scenes
from workflows.errors import InputError

log = logging.getLogger("deapull")
PACKAGES = ("deapull", "meshing", "fem_solver", "surrogate", "workflows")


def _rank() -> int:
    if "mpi4py" not in sys.modules:
        return 0
    from mpi4py import MPI
    return MPI.COMM_WORLD.rank


def setup_logging(verbose: bool = False) -> None:
    level = (logging.DEBUG if verbose else logging.INFO) if _rank() == 0 else logging.WARNING
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(name)s %(levelname)s: %(message)s",
                        datefmt="%H:%M:%S")
    for name in PACKAGES:
        logging.getLogger(name).setLevel(level)


def add_scene_args(p: argparse.ArgumentParser, required: bool = True) -> None:
    p.add_argument("--scene", required=required, help="shipped scene name or path to a TOML file")
    p.add_argument("--setup", default=None, help="setup of the scene (coin_pull: C1..C8; default: the scene's)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override one scene key (validated like the file); repeatable")


def load_scene(args) -> scenes.Scene:
    return scenes.load(args.scene, setup=args.setup, overrides=args.overrides)


def cmd_scenes(args) -> int:
    for name in scenes.list_scenes():
        sc = scenes.load(name)
        setups = scenes.setups_of(name)
        extra = f"  [setups: {', '.join(setups)}]" if setups else ""
        print(f"{name:16s} {sc.scene.description}{extra}")
    return 0


def cmd_show_scene(args) -> int:
    args.scene = args.name
    print(load_scene(args).to_toml(), end="")
    return 0


def cmd_mesh(args) -> int:
    sc = load_scene(args)
    from meshing.build import write_mesh
    path, summary = write_mesh(sc, args.out)
    print(f"wrote {path}")
    print(json.dumps(summary, indent=2))
    return 0


def cmd_plot(args) -> int:
    from workflows.report import plot_run
    print(f"wrote {plot_run(args.data, args.out)}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="deapull", description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("scenes", help="list the shipped scenes")
    p.set_defaults(func=cmd_scenes)

    p = sub.add_parser("show-scene", help="print the resolved scene as TOML")
    p.add_argument("name", help="shipped scene name or path")
    p.add_argument("--setup", default=None)
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE")
    p.set_defaults(func=cmd_show_scene)

    p = sub.add_parser("mesh", help="mesh a scene with gmsh (writes mesh.msh and mesh.json)")
    add_scene_args(p)
    p.add_argument("--out", required=True, help="output folder")
    p.set_defaults(func=cmd_mesh)

    p = sub.add_parser("plot", help="plot one FEM dataset (x, u, Fx, Fy, V against t)")
    p.add_argument("data", help="dataset file (.nc)")
    p.add_argument("--out", required=True, help="PNG file")
    p.set_defaults(func=cmd_plot)

    for module in _stage_clis():
        module.register(sub)
    return parser


def _stage_clis():
    """The stages that add sub-commands of their own (imported lazily: dolfinx and torch are slow)."""
    import importlib
    out = []
    for name in ("fem_solver.cli", "fem_solver.studies_cli", "surrogate.cli"):
        try:
            out.append(importlib.import_module(name))
        except ModuleNotFoundError as err:
            if err.name not in (name, name.split(".")[0]):
                raise
    return out


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    setup_logging(args.verbose)
    try:
        return int(args.func(args) or 0)
    except InputError as err:
        if _rank() == 0:
            print(f"deapull {args.command}: error: {err}", file=sys.stderr)
        return 2
