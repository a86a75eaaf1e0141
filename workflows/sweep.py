"""The setup sweep (``mpirun -n N deapull sweep``): every setup of a scene, one dataset each.

A case per setup on the study runner (:mod:`deapull.workflows.runner`): setups spread over
rank groups, each dataset ``<out>/<setup>.nc`` written atomically, a setup whose dataset is
complete skipped, so an interrupted sweep resumes and loses nothing. Rank 0 shows the
progress and the closing table.
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from deapull import dataset, scene as scenes
from deapull.errors import InputError
from deapull.workflows.runner import Case, run_cases, solve_case

log = logging.getLogger(__name__)
COLUMNS = (("setup", "case", "6s"), ("points", "steps", "6d"), ("travel mm", "travel_mm", "10.3f"),
           ("max Fy mN", "max_Fy_mN", "10.3f"), ("wall s", "wall_s", "8.1f"))


def sweep_cases(scene_name, setups, overrides) -> list[Case]:
    """Validate every setup's scene before any work; one case per setup."""
    available = scenes.setups_of(scene_name)
    if not available:
        raise InputError(f"scene {scene_name!r} has no setups to sweep")
    chosen = setups or available
    unknown = [s for s in chosen if s not in available]
    if unknown:
        raise InputError(f"--setups {unknown[0]!r}: unknown setup; allowed: {', '.join(available)}")
    for s in chosen:
        scenes.load(scene_name, setup=s, overrides=overrides)
    return [Case(s, scene_name, s, tuple(overrides), f"{scene_name} setup {s}") for s in chosen]


def sweep(scene_name, setups, out_dir, comm, ranks_per_setup: int = 1, overrides=()) -> list[dict]:
    """Run (or resume) the sweep; every rank returns the closing rows, in setup order."""
    out_dir = Path(out_dir)
    cases = sweep_cases(scene_name, setups, overrides)

    def solve(case, scene, out, group, progress):
        return solve_case(case, scene, out, group, progress, run_dir=out)

    def complete(case):
        return dataset.is_complete(out_dir / f"{case.name}.nc")

    if ranks_per_setup < 1 or comm.size % ranks_per_setup:
        raise InputError(f"--ranks-per-setup {ranks_per_setup}: must divide the number of ranks ({comm.size})")
    results = run_cases(cases, out_dir, comm, ranks_per_setup, desc="sweep", solve=solve, is_done=complete)
    return [_row(out_dir, case, result) for case, result in zip(cases, results)]


def _row(out_dir: Path, case: Case, result: dict | None) -> dict:
    """The table row of a setup: from its dataset (also one made before the run's JSON existed)."""
    path = out_dir / f"{case.name}.nc"
    if result is not None and result.get("status") not in ("ok", None):
        return {"case": case.name, "status": f"{result['status']}: {result.get('reason', '')}"}
    if not dataset.is_complete(path):
        return {"case": case.name, "status": "missing"}
    run = dataset.read(path, variables=("x", "Fy"))
    return {"case": case.name, "status": "ok", "steps": len(run.columns["x"]),
            "travel_mm": float(abs(run.columns["x"]).max()) * 1e3, "max_Fy_mN": float(run.columns["Fy"].max()) * 1e3,
            "wall_s": float(run.attrs["wall_time_total_s"])}


def format_table(rows) -> str:
    """The closing table, with the mean wall time beside the paper's (ABAQUS 130 s)."""
    head = " ".join(f"{h:>{spec[:-1].split('.')[0]}s}" if i else f"{h:6s}" for i, (h, _, spec) in enumerate(COLUMNS))
    lines = [head + "  status", "-" * 56]
    for r in rows:
        cells = []
        for i, (_, key, spec) in enumerate(COLUMNS):
            v = r.get(key)
            width = int(spec[:-1].split(".")[0])
            cells.append(format(v, spec) if v is not None else f"{'–':>{width}s}")
        lines.append(" ".join(cells) + f"  {r['status']}")
    walls = [r["wall_s"] for r in rows if r.get("wall_s") is not None and np.isfinite(r["wall_s"])]
    if walls:
        lines.append(f"mean wall time per setup {np.mean(walls):.1f} s (paper, ABAQUS: 130 s)")
    return "\n".join(lines)
