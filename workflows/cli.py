"""``deapull``: the verbs of the pipeline.

Every sub-command validates its input before any expensive work; bad input
(:class:`deapull.errors.InputError`) prints one clear line and exits with status 2.
Under MPI only rank 0 prints.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys

from deapull import scene as scenes
from deapull.errors import InputError
from deapull.workflows import cli_control, cli_fem, cli_report, cli_studies, cli_surrogate
from deapull.workflows.args import add_scene_args, load_scene

log = logging.getLogger("deapull")


def _rank() -> int:
    if "mpi4py" not in sys.modules:
        return 0
    from mpi4py import MPI  # lazy: only asked once a command has loaded MPI (importing it initialises MPI)
    return MPI.COMM_WORLD.rank


class QuietOthers(logging.Filter):
    """Pass deapull's own records, and other libraries' only from WARNING up.

    A first run compiles the FFCx forms: cffi imports setuptools, which raises the root
    logger to INFO, and every gcc call then logs a line ("running build_ext", the compiler
    command...). Those are debug detail for us: ``-v`` shows them.
    """

    def filter(self, record: logging.LogRecord) -> bool:
        return record.name.startswith("deapull") or record.levelno >= logging.WARNING


def setup_logging(verbose: bool = False) -> None:
    """deapull's INFO (DEBUG with ``-v``) on rank 0, warnings only elsewhere and from other libraries."""
    level = (logging.DEBUG if verbose else logging.INFO) if _rank() == 0 else logging.WARNING
    handler = logging.StreamHandler()
    handler.setFormatter(logging.Formatter("%(asctime)s %(name)s %(levelname)s: %(message)s", datefmt="%H:%M:%S"))
    if not verbose:
        handler.addFilter(QuietOthers())
    logging.basicConfig(level=logging.DEBUG if verbose else logging.WARNING, handlers=[handler], force=True)
    logging.getLogger("deapull").setLevel(level)


def cmd_scenes(args) -> int:
    for name in scenes.list_scenes():
        sc = scenes.load(name)
        setups = scenes.setups_of(name)
        extra = f"  [setups: {', '.join(setups)}]" if setups else ""
        print(f"{name:16s} {sc.scene.description}{extra}")
    return 0


def cmd_show_scene(args) -> int:
    if args.keys:
        print(scenes.keys_markdown(), end="")
        return 0
    args.scene = args.name
    print(load_scene(args).to_toml(), end="")
    return 0


def cmd_docs(args) -> int:
    from deapull.workflows import docs_tables
    if args.check:
        stale = docs_tables.stale_pages()
        for page in stale:
            print(f"{page}: its results tables differ from the results files (run deapull docs)", file=sys.stderr)
        return 1 if stale else 0
    for page in docs_tables.write_pages():
        print(f"rewrote {page}")
    return 0


def cmd_mesh(args) -> int:
    sc = load_scene(args)
    from deapull.meshing.build import write_mesh  # lazy: gmsh loads only when this command runs
    path, summary = write_mesh(sc, args.out)
    print(f"wrote {path}")
    print(json.dumps(summary, indent=2))
    return 0


def cmd_plot(args) -> int:
    from deapull.workflows.plot_run import plot_run  # lazy: matplotlib loads only for a plot
    print(f"wrote {plot_run(args.data, args.out)}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="deapull", description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("scenes", help="list the shipped scenes")
    p.set_defaults(func=cmd_scenes)

    p = sub.add_parser("show-scene", help="print the resolved scene as TOML (--keys: every key, as Markdown)")
    p.add_argument("name", nargs="?", default="coin_pull", help="shipped scene name or path (default coin_pull)")
    p.add_argument("--keys", action="store_true", help="print the table of every scene key (docs/scene_keys.md)")
    add_scene_args(p, scene=False)
    p.set_defaults(func=cmd_show_scene)

    p = sub.add_parser("docs", help="rewrite the README's and docs/' results tables from the committed results files")
    p.add_argument("--check", action="store_true", help="only check: exit 1 naming each page that differs")
    p.set_defaults(func=cmd_docs)

    p = sub.add_parser("mesh", help="mesh a scene with gmsh (writes mesh.msh and mesh.json)")
    add_scene_args(p)
    p.add_argument("--out", required=True, help="output folder")
    p.set_defaults(func=cmd_mesh)

    p = sub.add_parser("plot", help="plot one FEM dataset (x, u, Fx, Fy, V against t)")
    p.add_argument("data", help="dataset file (.nc)")
    p.add_argument("--out", required=True, help="PNG file")
    p.set_defaults(func=cmd_plot)

    for module in (cli_fem, cli_studies, cli_surrogate, cli_control, cli_report):   # each imports its stage lazily
        module.register(sub)
    return parser


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
