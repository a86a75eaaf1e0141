"""The setup sweep (``mpirun -n N deapull sweep``): every setup of a scene, one dataset each.

A case per setup (and protocol) on the study runner (:mod:`deapull.workflows.runner`): cases
spread over rank groups, each dataset written atomically, a case whose dataset is complete
skipped, so an interrupted sweep resumes and loses nothing. Rank 0 shows the progress and
the closing table.

``--protocols`` picks the voltage protocols (:data:`PROTOCOL_SETS`): ``scene`` (default) plays
the scene's own protocol into ``<out>/<setup>.nc``; ``excitation`` plays the inputs a
controller applies — ramp–hold–ramp, triangle, release and three seeded random piecewise-linear
inputs — into ``<out>/<setup>_<protocol>.nc`` (file names say the setup and the protocol);
``push`` plays the MPC's full push (the scene's ramp in 80 ms, 1 ms steps, then held) into
``<out>/<setup>_fast.nc``, with the rim band where a fast push crosses the rim and a stiffer table. A case's overrides
are ``--fidelity``'s, then the protocol set's, then ``--set``'s.
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from deapull import dataset, scene as scenes
from deapull.errors import InputError
from deapull.paper import ABAQUS_S
from deapull.workflows.runner import Case, run_cases, solve_case

log = logging.getLogger(__name__)
#: named sets of protocols: {set: {protocol name: --set overrides of [load]}} ("" = the scene's own)
PROTOCOL_SETS = {
    "scene": {"": ()},
    "excitation": {
        "rhr": ("load.protocol='ramp_hold_ramp'", "load.ramp_time_s=0.5", "load.hold_time_s=0.2",
                "load.voltage_end_V=150.0", "load.ramp_down_time_s=0.3", "load.end_time_s=1.0"),
        "triangle": ("load.protocol='triangle'", "load.ramp_time_s=0.5", "load.end_time_s=1.0"),
        # placed at 400 V on the still coin, the free edge crosses the rim at |z| ~ 1.9-2.5 mm, and the
        # DEA presses the table harder (coin_release.toml)
        "release": ("load.protocol='release'", "load.ramp_time_s=1.0", "load.end_time_s=1.0",
                    "mesh.rim_band_width_m=0.0", "mesh.rim_band_m=[0.0015, 0.004]", "mesh.rim_band_divisions=5",
                    "table.penalty_N_m3=2e12"),
        **{f"random{k}": ("load.protocol='random'", f"load.seed={k}", "load.rate_max_V_s=2000.0",
                          "load.segment_min_s=0.05", "load.segment_max_s=0.2", "load.end_time_s=1.0")
           for k in (1, 2, 3)},
    },
    # the MPC's full push (5 V per 1 ms step: 0 -> 400 V in 80 ms), then 200 ms held: the coin moves
    # ~30 mm/s at the top, twelve times the ramp's speed, and coasts after it (docs/control.md); the
    # coin's pull presses the DEA into the table harder than on the ramps: the table twice as stiff. The
    # friction's regularisation is 1e-4 m/s, 1/300 of the push's coin speed (at the scene's 1e-5 the
    # tip's fast onset of slip costs 30-40 s per 1 ms step; what it changes: docs/datasets.md)
    "push": {
        "fast": ("load.ramp_time_s=0.08", "load.end_time_s=0.28", "time.dt_max_s=0.001", "table.penalty_N_m3=2e12",
                 "contact.slip_rate_regularisation_m_s=1e-4"),
    },
}
COLUMNS = (("setup", "case", "12s"), ("points", "steps", "6d"), ("travel mm", "travel_mm", "10.3f"),
           ("max Fy mN", "max_Fy_mN", "10.3f"), ("steps < min pts", "below_min", "15d"), ("wall s", "wall_s", "8.1f"))


def sweep_cases(scene_name, setups, overrides, protocols: str = "scene", fidelity=()) -> list[Case]:
    """Validate every case's scene before any work; one case per setup and protocol.

    A case's overrides are the fidelity's (``--fidelity``), then the protocol set's (so a set can
    carry the mesh its protocol needs), then the user's ``--set`` (which win).
    """
    available = scenes.setups_of(scene_name)
    if not available:
        raise InputError(f"scene {scene_name!r} has no setups to sweep")
    if protocols not in PROTOCOL_SETS:
        raise InputError(f"--protocols {protocols!r}: expected one of {', '.join(PROTOCOL_SETS)}")
    chosen = setups or available
    unknown = [s for s in chosen if s not in available]
    if unknown:
        raise InputError(f"--setups {unknown[0]!r}: unknown setup; allowed: {', '.join(available)}")
    cases = []
    for s in chosen:
        for pname, sets in PROTOCOL_SETS[protocols].items():
            every = (*fidelity, *sets, *overrides)          # the user's --set last: it wins
            scenes.load(scene_name, setup=s, overrides=every)
            name = f"{s}_{pname}" if pname else s
            cases.append(Case(name, scene_name, s, every, f"{scene_name} setup {s}" + (f", {pname}" if pname else "")))
    return cases


def sweep(scene_name, setups, out_dir, comm, ranks_per_setup: int = 1, overrides=(),
          protocols: str = "scene", fidelity=()) -> list[dict]:
    """Run (or resume) the sweep; every rank returns the closing rows, in case order."""
    out_dir = Path(out_dir)
    cases = sweep_cases(scene_name, setups, overrides, protocols, fidelity)

    def solve(case, scene, out, group, progress):
        return solve_case(case, scene, out, group, progress, run_dir=out, name=case.name)

    def complete(case, scene):
        # a dataset made with another resolved scene (a changed scene file or default) is redone
        return scene is not None and dataset.is_complete(out_dir / f"{case.name}.nc", scene.to_toml())

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
            "below_min": run.attrs.get("contact_steps_below_min_points"),   # None before the count
            "wall_s": float(run.attrs["wall_time_total_s"])}


def format_table(rows) -> str:
    """The closing table, with the mean wall time beside the paper's (ABAQUS, :data:`deapull.paper.ABAQUS_S`)."""
    widths = [int(spec[:-1].split(".")[0]) for _, _, spec in COLUMNS]
    head = " ".join(f"{h:<{w}s}" if i == 0 else f"{h:>{w}s}" for i, ((h, _, _), w) in enumerate(zip(COLUMNS, widths)))
    lines = [head + "  status", "-" * (len(head) + 8)]
    for r in rows:
        cells = [format(r[key], spec) if r.get(key) is not None else f"{'–':>{w}s}"
                 for (_, key, spec), w in zip(COLUMNS, widths)]
        lines.append(" ".join(cells) + f"  {r['status']}")
    thin = [r["case"] for r in rows if r.get("below_min")]
    if thin:
        lines.append(f"WARNING: {len(thin)} case(s) had steps with fewer contact points than contact.min_active_points "
                     f"({', '.join(thin)}): the contact patch is not resolved there (docs/fem_accuracy.md)")
    walls = [r["wall_s"] for r in rows if r.get("wall_s") is not None and np.isfinite(r["wall_s"])]
    if walls:
        lines.append(f"mean wall time per setup {np.mean(walls):.1f} s (paper, ABAQUS: {ABAQUS_S:g} s)")
    return "\n".join(lines)
