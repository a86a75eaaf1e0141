"""Reading the studies' tables (CSV, Markdown pipe tables) and formatting their numbers."""
from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path


def fmt(value, spec: str = ".3g", unit: str = "") -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    return format(value, spec) + (f" {unit}" if unit else "")


def csv_text(rows: list[dict], columns) -> str:
    """Rows as CSV text with every number at full precision (None and NaN: empty cells)."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(columns)
    for r in rows:
        cells = []
        for c in columns:
            v = r.get(c)
            cells.append("" if v is None or (isinstance(v, float) and not math.isfinite(v)) else
                         repr(v) if isinstance(v, float) else str(v))
        writer.writerow(cells)
    return buf.getvalue()


def read_csv(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def run_config(folder: Path) -> dict:
    """The ``config`` of a ``deapull control`` run (its ``run.json`` in ``folder``); {} without one."""
    path = Path(folder) / "run.json"
    return (json.loads(path.read_text()).get("config") or {}) if path.is_file() else {}


def num(row: dict, key: str) -> float | None:
    try:
        v = float(row.get(key, ""))
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None
