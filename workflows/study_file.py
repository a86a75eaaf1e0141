"""Studies as data: the cases of the fidelity ladder and the stability suite, read from ``studies/*.toml``.

A study file has ``[study]`` (its name, description and the keys its command reads) and
``[cases]``, one entry per case: a list of ``--set`` overrides, or a table ``[cases.<name>]``:

* ``set``: the case's ``--set`` overrides, applied after the study's protocol;
* ``description``: one line (default: the overrides);
* keys of the command: the stability suite's ``scene`` and ``expected``; the ladder's ``resolution``
  and ``steps``. An unknown key is an error naming the allowed ones.

An override's value may be relative to the scene it runs on: ``@section.key*f`` is f times that key
of the case's base scene (the scene as loaded with ``--fidelity`` and ``--set``, after the study's
protocol), ``@section.key+n`` adds n. An integer key stays an integer (rounded down, at least 1).
So ``contact.penalty_N_m3=@contact.penalty_N_m3*100`` is a hundred times the penalty of whatever
scene the study runs on.
"""
from __future__ import annotations

import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from deapull.errors import InputError
from deapull.workflows.args import shipped_toml

STUDY_DIR = Path(__file__).resolve().parents[1] / "studies"
RELATIVE = re.compile(r"^@([a-z_]+)\.([A-Za-z_0-9]+)\s*([*+])\s*(\S+)$")


@dataclass(frozen=True)
class Entry:
    """One case of a study file."""
    name: str
    set: tuple[str, ...]
    description: str
    keys: dict = field(default_factory=dict)     # the command's own keys (scene, expected, …)


def study_path(name_or_path: str | Path) -> Path:
    """A study shipped in ``studies/`` by name, or a path to a TOML file."""
    return shipped_toml(name_or_path, STUDY_DIR, "--study", "study")


def read(name_or_path: str | Path) -> tuple[Path, dict]:
    """The study file's path and its TOML, with ``[study]`` and ``[cases]`` present."""
    path = study_path(name_or_path)
    try:
        study = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as err:
        raise InputError(f"{path}: not valid TOML ({err})") from None
    for key in ("study", "cases"):
        if key not in study:
            raise InputError(f"{path}: missing [{key}]")
    return path, study


def check_overrides(path: Path, where: str, value) -> tuple[str, ...]:
    """``value`` as a tuple of ``section.key=value`` strings, or an InputError naming ``where``."""
    if not isinstance(value, list) or not all(isinstance(o, str) and "=" in o for o in value):
        raise InputError(f"{path}: {where} = {value!r}: expected a list of 'section.key=value'")
    return tuple(value)


def load(name_or_path: str | Path, keys: dict) -> tuple[dict, dict[str, Entry]]:
    """``[study]`` and the cases of a study file, checked. ``keys``: the command's own case keys,
    each with its allowed values (a tuple) or None (any value)."""
    path, study = read(name_or_path)
    head = dict(study["study"], path=str(path))
    head["set"] = check_overrides(path, "study.set", head.get("set", []))
    entries = {}
    for name, table in study["cases"].items():
        table = {"set": table} if isinstance(table, list) else table
        if not isinstance(table, dict):
            raise InputError(f"{path}: cases.{name} = {table!r}: expected a list of overrides or a table "
                             f"[cases.{name}]")
        unknown = [k for k in table if k not in ("set", "description", *keys)]
        if unknown:
            raise InputError(f"{path}: cases.{name}.{unknown[0]}: unknown key; allowed: "
                             f"{', '.join(('set', 'description', *keys))}")
        for k, allowed in keys.items():
            if k in table and allowed is not None and table[k] not in allowed:
                raise InputError(f"{path}: cases.{name}.{k} = {table[k]!r}: expected one of {', '.join(map(str, allowed))}")
        sets = check_overrides(path, f"cases.{name}.set", table.get("set", []))
        entries[name] = Entry(name, sets, table.get("description") or ", ".join(sets) or "as loaded",
                              {k: table[k] for k in keys if k in table})
    if not entries:
        raise InputError(f"{path}: [cases] is empty")
    return head, entries


def pick(entries: dict[str, Entry], names, option: str) -> list[Entry]:
    """The entries ``names`` picks (all when None); an unknown name is an error naming the allowed."""
    unknown = [n for n in names or () if n not in entries]
    if unknown:
        raise InputError(f"{option} {unknown[0]!r}: unknown case; allowed: {', '.join(entries)}")
    return [e for e in entries.values() if not names or e.name in names]


def resolve(assignments, base, where: str = "study") -> tuple[str, ...]:
    """The overrides with every relative value (``@section.key*f``, ``@section.key+n``) made absolute
    on the loaded scene ``base``."""
    out = []
    for assignment in assignments:
        key, _, text = assignment.partition("=")
        m = RELATIVE.match(text.strip())
        if not text.strip().startswith("@"):
            out.append(assignment)
            continue
        if m is None:
            raise InputError(f"{where}: {assignment!r}: expected key=@section.key*factor or key=@section.key+number")
        section, name, op, number = m.groups()
        value = getattr(getattr(base, section, None), name, None)
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            raise InputError(f"{where}: {assignment!r}: @{section}.{name} is not a number of the scene "
                             f"({value!r})")
        try:
            operand = float(number)
        except ValueError:
            raise InputError(f"{where}: {assignment!r}: {number!r} is not a number") from None
        result = value * operand if op == "*" else value + operand
        if isinstance(value, int):
            result = max(int(math.floor(result)), 1)
        out.append(f"{key.strip()}={result!r}")
    return tuple(out)
