"""The one argument helper of every ``deapull`` sub-command that reads a scene.

``--scene``, ``--setup``, ``--fidelity`` and ``--set SECTION.KEY=VALUE`` (repeatable) mean
the same in every command; :func:`load_scene` validates them like the file (bad input raises
:class:`deapull.errors.InputError` before any work).
"""
from __future__ import annotations

import argparse
from pathlib import Path

from deapull import scene as scenes
from deapull.errors import InputError


def add_scene_args(p: argparse.ArgumentParser, scene: bool = True, setup: bool = True,
                   scene_default: str | None = None, set_help: str | None = None, fidelity: bool = True) -> None:
    """Add ``--scene`` (required unless ``scene_default``), ``--setup``, ``--fidelity`` and ``--set``."""
    if scene:
        p.add_argument("--scene", required=scene_default is None, default=scene_default,
                       help="shipped scene name or path to a TOML file"
                            + (f" (default {scene_default})" if scene_default else ""))
    if setup:
        p.add_argument("--setup", default=None, help="setup of the scene (coin_pull: C1..C8; default: the scene's)")
    if fidelity:
        add_fidelity_arg(p)
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help=set_help or "override one scene key (validated like the file); repeatable")


def add_fidelity_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--fidelity", default=None, metavar="NAME",
                   help="a named fidelity of the scene file ([fidelities.NAME]; coin_pull: preview, the quick "
                        "look), applied before --set; default: the file as written, the data fidelity")


def overrides_of(args, scene_name=None) -> tuple[str, ...]:
    """``--fidelity``'s overrides, then the user's ``--set`` (which win)."""
    name = scene_name if scene_name is not None else args.scene
    return (*scenes.fidelity_overrides(name, getattr(args, "fidelity", None)), *args.overrides)


def load_scene(args) -> scenes.Scene:
    """The scene that ``--scene/--setup/--fidelity/--set`` name, validated."""
    return scenes.load(args.scene, setup=args.setup, overrides=overrides_of(args))


def names(text: str) -> list[str] | None:
    """``"a, b"`` → ``["a", "b"]``; an empty text → None (meaning: all)."""
    out = [s.strip() for s in text.split(",") if s.strip()]
    return out or None


def shipped_toml(name_or_path, folder: Path, option: str, what: str) -> Path:
    """A TOML file shipped in ``folder`` by name (``folder/NAME.toml``), or a path to one; an unknown
    name or a missing file is an :class:`InputError` naming ``option`` and the shipped names."""
    p = Path(name_or_path)
    if p.suffix == ".toml":
        if not p.is_file():
            raise InputError(f"{option} {str(name_or_path)!r}: no such file")
        return p
    path = Path(folder) / f"{name_or_path}.toml"
    if not path.is_file():
        shipped = ", ".join(sorted(q.stem for q in Path(folder).glob("*.toml")))
        raise InputError(f"{option} {str(name_or_path)!r}: unknown {what}; shipped: {shipped}")
    return path
