"""Output that is whole or absent: one atomic write, and one CSV / Markdown table writer.

Every file the project writes goes through :func:`atomic_write`: the content is written
to a temporary file in the target's folder and renamed over the target, so a file that
exists is complete, and an interrupted run leaves no half-written file behind (the
temporary file is removed on any error).
"""
from __future__ import annotations

import csv
import io
import json
import math
import os
import tempfile
from pathlib import Path
from typing import Callable, Iterable, Sequence

import numpy as np


def atomic_write(path: str | os.PathLike, write: Callable[[str], object], suffix: str = ".tmp") -> Path:
    """Call ``write(tmp_path)`` on a temporary file beside ``path``, then rename it to ``path``.

    Parameters
    ----------
    path : path-like
        The target; its folder is created.
    write : callable
        Writes the whole content to the temporary path it is given (e.g.
        ``lambda p: ds.to_netcdf(p)``, ``lambda p: torch.save(state, p)``).
    suffix : str
        Ending of the temporary file's name (for writers that choose the format by it).

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=suffix)
    os.close(fd)
    try:
        write(tmp)
        os.chmod(tmp, 0o666 & ~_umask())   # as an ordinary open() would have made it
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return path


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_text(path: str | os.PathLike, text: str) -> Path:
    """Atomically write ``text``."""
    return atomic_write(path, lambda p: Path(p).write_text(text))


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"not JSON serialisable: {value!r}")


def write_json(path: str | os.PathLike, obj, indent: int = 1) -> Path:
    """Atomically write ``obj`` as JSON (numpy scalars and arrays, paths allowed)."""
    return write_text(path, json.dumps(obj, indent=indent, default=_json_default) + "\n")


def cell(value, spec: str = ".3g", escape: bool = True) -> str:
    """A table cell: numbers formatted, NaN and None as '–', booleans as yes/no.

    ``spec = "s"``: a time in seconds, one decimal from 1 s on, two significant digits
    below (a surrogate's rollout takes milliseconds).
    """
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    if isinstance(value, (bool, np.bool_)):
        return "yes" if value else "no"
    if isinstance(value, (int, float, np.number)):
        if spec == "s":
            spec = ".1f" if abs(value) >= 1 else ".2g"
        return format(value, spec)
    return str(value).replace("|", "\\|") if escape else str(value)


def table_record(rows: Iterable[dict], columns: Sequence[tuple[str, str, str]]) -> dict:
    """A table as data, ``{"headers": [...], "rows": [[cell, ...], ...]}`` with the cells formatted
    (:func:`cell`); ``columns`` are (header, key, format spec) triples. What a stage writes into its
    results JSON for the report and the docs to show as it is."""
    return {"headers": [h for h, _, _ in columns],
            "rows": [[cell(row.get(k), spec, escape=False) for _, k, spec in columns] for row in rows]}


def markdown_table(rows: Iterable[dict], columns: Sequence[tuple[str, str, str]]) -> str:
    """A Markdown table; ``columns`` are (header, key, format spec) triples (see :func:`cell`)."""
    return markdown_of(table_record(rows, columns))


def markdown_of(table: dict) -> str:
    """A :func:`table_record` as a Markdown table."""
    def esc(text: str) -> str:
        return str(text).replace("|", "\\|")
    lines = ["| " + " | ".join(esc(h) for h in table["headers"]) + " |", "|" + "---|" * len(table["headers"])]
    lines += ["| " + " | ".join(esc(c) for c in row) + " |" for row in table["rows"]]
    return "\n".join(lines)


def _csv_value(value):
    if isinstance(value, (list, tuple)):
        return " ".join(str(v) for v in value)
    if isinstance(value, np.generic):
        return value.item()
    return "" if value is None else value


def write_csv(path: str | os.PathLike, rows: Iterable[dict], columns: Sequence[str]) -> Path:
    """Atomically write ``rows`` as CSV with the header ``columns`` (missing keys empty, lists
    space-separated)."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(columns), extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({c: _csv_value(row.get(c)) for c in columns})
    return write_text(path, buf.getvalue())
