"""The figures in the README and docs/, generated from the committed results files.

A page carries a block ``<!-- results:NAME -->`` … ``<!-- /results:NAME -->``; ``deapull docs``
rewrites every block from its results file (:data:`BLOCKS`), and ``deapull docs --check`` (and a
test) fails when a page differs from what its results say, so no table can go stale.
"""
from __future__ import annotations

import json
import math
import re
from pathlib import Path

from deapull.io import atomic_write
from deapull.paper import ABAQUS_S

REPO = Path(__file__).resolve().parents[1]
PAGES = ("README.md", "docs/physics.md", "docs/fem_accuracy.md")


def _f(value, fmt: str) -> str:
    return "–" if value is None or (isinstance(value, float) and not math.isfinite(value)) else format(value, fmt)


def contact_reference(result: dict) -> str:
    """The contact ladders: per case, then per ladder its order, Richardson value and GCI; the bound."""
    t = result["time_s"]
    lines = [f"| case | dofs | wall s (1 core) | x({t:g} s) mm | x(1 s) mm | peak overlap µm | fewest contact points |",
             "|---|---|---|---|---|---|---|"]
    for name, c in result["cases"].items():
        lines.append(f"| {name} | {c.get('dofs', '–')} | {_f(c.get('wall_s'), '.0f')} | {_f(c['x_at_t_mm'], '.4f')} | "
                     f"{_f(c['x_end_mm'], '.4f')} | {_f(c['peak_overlap_um'], '.2f')} | {c['min_points']} |")
    lines += ["", f"| ladder | x({t:g} s) mm, coarse / middle / fine | observed order | order of the x(t) MAE | "
                  "Richardson mm | GCI % |", "|---|---|---|---|---|---|"]
    for name, lad in result["ladders"].items():
        xs = " / ".join(_f(v, ".4f") for v in lad["x_at_t_mm"])
        if not lad.get("complete", True):
            ch = ", ".join(_f(c, "+.3f") + " %" if c is not None else "–" for c in lad["changes_percent"])
            lines.append(f"| {lad['label']} | {xs} | – (incomplete; level to level {ch}) | – | – | – |")
            continue
        lines.append(f"| {lad['label']} | {xs} | {_f(lad['observed_order_x_at_t'], '.2f')} | "
                     f"{_f(lad['observed_order_mae_x'], '.2f')} | {_f(lad['richardson_x_at_t_mm'], '.4f')} | "
                     f"{_f(lad['gci_x_at_t_percent'], '.3f')} |")
    lines += ["", f"* halving the step changes x({t:g} s) by {_f(result['dt_change_percent'], '.3f')} %;",
              f"* the bound (the ladders' GCIs and the step's change): **{_f(result['bound_percent'], '.3f')} %** "
              f"(goal ≤ 1 %); the reference x({t:g} s) = {_f(result['reference_x_at_t_mm'], '.4f')} mm;"]
    if "default_error_percent" in result:
        lines.append(f"* the data fidelity (the scene file as written): **{result['default_error_percent']:+.3f} %** "
                     "against it (goal within 2 %);")
    for name, pair in result.get("pairs", {}).items():
        lines.append(f"* {name}: {pair['change_percent']:+.3f} % on x({t:g} s);")
    if result.get("failed"):
        lines.append("* failed: " + "; ".join(f"{k} ({v})" for k, v in result["failed"].items()) + ";")
    if result.get("not_run"):
        lines.append("* not solved yet: " + ", ".join(result["not_run"]) + ";")
    lines[-1] = lines[-1].rstrip(";") + "."
    return "\n".join(lines)


def headline(result: dict) -> str:
    """The README's results table: ours beside the paper's where it has one."""
    default = result["cases"].get(result.get("default_case", "default"), {})
    t = result["time_s"]
    rows = ["| what | ours | paper |", "|---|---|---|",
            f"| FEM of one 0→400 V ramp (coin_pull C3), one shared core | {_f(default.get('wall_s'), '.0f')} s at "
            f"{default.get('dofs', '–')} dofs | {ABAQUS_S:.0f} s (ABAQUS) |",
            f"| coin travel, C3 at 400 V | {_f(default.get('travel_mm'), '.3f')} mm | ≈ 1 mm (Fig. 4) |",
            f"| mesh-convergence bound on x({t:g} s) (two ladders + the step) | {_f(result['bound_percent'], '.2f')} % "
            "| – |",
            f"| data fidelity against the Richardson value | {_f(result.get('default_error_percent'), '+.2f')} % | – |",
            f"| fewest contact points carrying the coin (data fidelity) | {default.get('min_points', '–')} | – |"]
    return "\n".join(rows)


#: block name -> (results file, renderer)
BLOCKS = {
    "contact_reference": ("bench/reference/contact_reference.json", contact_reference),
    "headline": ("bench/reference/contact_reference.json", headline),
}

_BLOCK = re.compile(r"(<!-- results:(?P<name>[\w-]+) -->\n)(?P<body>.*?)(\n<!-- /results:(?P=name) -->)", re.S)


def render(text: str, root: Path = REPO) -> str:
    """``text`` with every results block rewritten from its file (a block whose file is missing says so)."""
    def block(m):
        name = m.group("name")
        if name not in BLOCKS:
            raise KeyError(f"unknown results block {name!r}; known: {', '.join(BLOCKS)}")
        path, make = BLOCKS[name]
        source = root / path
        body = (make(json.loads(source.read_text())) if source.is_file()
                else f"*{path} is missing: run the command that writes it (docs/fem_accuracy.md).*")
        return m.group(1) + body + m.group(4)
    return _BLOCK.sub(block, text)


def stale_pages(root: Path = REPO) -> list[str]:
    """The pages whose results blocks differ from their files."""
    return [p for p in PAGES if (root / p).is_file() and render((root / p).read_text(), root) != (root / p).read_text()]


def write_pages(root: Path = REPO) -> list[str]:
    """Rewrite the stale pages; return them."""
    stale = stale_pages(root)
    for p in stale:
        atomic_write(root / p, lambda path, text=render((root / p).read_text(), root): Path(path).write_text(text))
    return stale
