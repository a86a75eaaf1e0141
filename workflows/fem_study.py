"""FEM accuracy studies of coin_pull C3 (issues 12, 23): the reference (the resolved
contact patch at three element sizes; converged in the tip zone and the penalty only: the runs
refined in the layers and the underside, ``bench/reference/beyond_the_ladder.json``, move its
travel 5-9 %, and its table prints them), the contact rule on it, the scene file (the fast preview) and
the datasets' fidelity ``resolved`` each with its rule doubled, ``resolved`` refined one direction at a
time (``refine``), the contact quadrature, the friction regularisation ε_v and the candidate meshes.

    deapull fem-study --study shipped|reference|refine|patch-rule|quadrature|friction|candidates|all --out out/fem_study

Each case is one ``deapull solve`` run (one core) into ``<out>/<case>/C3.nc``; a case whose
dataset exists is not run again (the study resumes). The table compares every case with
the reference: the finest half-model run, and the Richardson estimate of the travel from
the three reference levels (observed order, error bound). It is printed and written as
``<out>/<study>.csv`` / ``.md``; ``<out>/reference.json`` keeps the reference's numbers
(``bench/bench_fem.py`` and ``--study shipped`` read the committed copy in ``bench/reference/``).
"""
from __future__ import annotations

import argparse
import json
import logging
import math
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from deapull import dataset, scene as scenes
from deapull.errors import InputError
from deapull.io import atomic_write, markdown_table, write_csv, write_json, write_text

log = logging.getLogger(__name__)

HALF = ("mesh.symmetry='half_z'",)
#: the default before issue 12 (as bench/bench_fem.py pins it)
OLD_DEFAULT = ("mesh.symmetry='none'", "mesh.n_length=16", "mesh.n_width=2", "mesh.n_active=1", "mesh.n_passive=1",
               "mesh.x_grading=1.0", "contact.quadrature_rule='gauss'", "contact.quadrature_degree=4",
               "solver.linear_solver='mumps'", "contact.slip_rate_regularisation_m_s=1e-4",
               "time.placement_first_step=1.0")
UMF = ("solver.linear_solver='umfpack'",)


def mesh(n_length, n_width, n_active=1, n_passive=1):
    return (f"mesh.n_length={n_length}", f"mesh.n_width={n_width}", f"mesh.n_active={n_active}",
            f"mesh.n_passive={n_passive}")


def quad(rule, degree):
    return (f"contact.quadrature_rule='{rule}'", f"contact.quadrature_degree={degree}")


def patch(size_mm: float, degree: int = 16) -> tuple:
    """The resolved contact patch (issue 23): the shipped 16 x 1 x 1 x 1 half model away from the
    tip, a 2 mm tip zone from the free end and the rim band 3 <= z <= 5 mm (where the free edge
    crosses the coin's rim) in ``size_mm`` elements; ``degree`` 16 = 9 x 9 Gauss contact points
    per facet (8: 5 x 5); the shipped 1/720 s step and the table."""
    n = round(2.0 / size_mm)
    return ("mesh.tip_zone_m=0.002", f"mesh.tip_zone_divisions={n}", "mesh.rim_band_m=[0.003,0.005]",
            f"mesh.rim_band_divisions={n}", f"contact.quadrature_degree={degree}")


def stiff(size_mm: float, times: int) -> tuple:
    """The resolved patch of ``size_mm`` with the coin's penalty ``times`` the shipped 2.24e9 N/m^3."""
    return (*patch(size_mm), f"contact.penalty_N_m3={2.24e9 * times:g}")


#: the reference ladder (issue 23): the resolved patch at 1 / 0.5 / 0.25 mm with the coin's
#: penalty x 1000 (near rigid: at most ~2 um into the coin), 9 x 9 Gauss points per contact facet.
#: At the shipped penalty the resolved patch sinks ~0.1 mm into the coin, so the old ladder
#: (2 / 1 / 0.5 mm at x 1, now the study ``patch-soft``) converged to a softer coin's travel.
PATCH_SIZES_MM = (1.0, 0.5, 0.25)
REFERENCE_TIMES = 1000
REFERENCE = {f"patch-{h:g}mm-9x9-k{REFERENCE_TIMES}": stiff(h, REFERENCE_TIMES) for h in PATCH_SIZES_MM}
REFERENCE_RATIOS = (PATCH_SIZES_MM[0] / PATCH_SIZES_MM[1], PATCH_SIZES_MM[1] / PATCH_SIZES_MM[2])
REFERENCE_ORDER = tuple(REFERENCE)
#: the penalty's share of the bound: the 0.5 mm level at x 100 against x 1000 (the travel's
#: penalty error goes as 1/k_n, so the x 1000 level keeps 1/9 of their difference)
PENALTY_PAIR = ("patch-0.5mm-9x9-k100", f"patch-0.5mm-9x9-k{REFERENCE_TIMES}")
REFERENCE[PENALTY_PAIR[0]] = stiff(0.5, 100)
#: the resolved patch at the shipped penalty (the reference before the near-rigid ladder)
SOFT_SIZES_MM = (2.0, 1.0, 0.5)
PATCH_SOFT = {f"patch-{h:g}mm-9x9": patch(h) for h in SOFT_SIZES_MM}
PATCH_FINE = {"patch-0.25mm-9x9": patch(0.25)}
#: the contact rule on the patch levels: 5 x 5 against the soft ladder's 9 x 9
PATCH_RULE = {f"patch-{h:g}mm-5x5": patch(h, 8) for h in SOFT_SIZES_MM}
#: the coin's penalty x 10 to x 1000 on the resolved patch, and x 100, x 1000 on the shipped mesh (at the
#: shipped penalty the resolved patch sinks far deeper into the coin than the shipped mesh's one point:
#: docs/fem_accuracy.md)
PATCH_PENALTY = {**{f"patch-{h:g}mm-9x9-k{k}": stiff(h, k)
                    for h, ks in ((1.0, (10, 100, 1000)), (0.5, (100, 1000)), (0.25, (1000,))) for k in ks},
                 **{f"shipped-k{k}": (f"contact.penalty_N_m3={2.24e9 * k:g}",) for k in (100, 1000)}}

#: the uniform ladder that was the reference before issue 23 (no tip zone; it oscillates because
#: one point per facet row decides the contact, docs/fem_accuracy.md): half model, in plane
#: x 1.5 then x 4/3, 2 elements per layer, 5 x 5 Gauss points, a 1/180 s cap
REF_DT = "time.dt_max_s=0.0055555555555556"
LADDER = ((16, 8), (24, 12), (32, 16))
#: coarser levels of the same family (12 x 6 departs from the others by a stick episode)
EXTRA_LEVELS = ((8, 4), (12, 6))


def ladder(levels) -> dict:
    """The uniform ladder's cases: half model, n x w in plane, 2 elements per layer, 5 x 5 Gauss points, 1/180 s."""
    return {f"ref-{n}x{w}x2x2": (*HALF, *UMF, *mesh(n, w, 2, 2), *quad("gauss", 8), REF_DT) for n, w in levels}


UNIFORM = ladder(LADDER)
LEVELS = ladder(EXTRA_LEVELS)
DT = {"dt-16x8x2x2-720": (*HALF, *UMF, *mesh(16, 8, 2, 2), *quad("gauss", 8))}
#: the scene file as written (the fast preview), its contact rule doubled (5 x 5 -> 9 x 9), and the same
#: two for the datasets' fidelity ``resolved`` (11 x 11 -> 22 x 22)
RESOLVED = scenes.fidelity_overrides("coin_pull", "resolved")
SHIPPED = {"shipped": (), "shipped-9x9": quad("gauss", 16), "resolved": RESOLVED,
           "resolved-22x22": (*RESOLVED, *quad("gauss", 42))}

QUADRATURE = {f"q-{n}x{w}-{rule}{deg}": (*HALF, *UMF, *mesh(n, w), *quad(rule, deg))
              for n, w in ((16, 2), (16, 4), (32, 4))
              for rule, deg in (("gauss", 4), ("gauss", 8), ("gauss_lobatto", 4), ("gauss_lobatto", 8))}

FRICTION = {f"eps-{n}x{w}-{eps:g}": (*HALF, *UMF, *mesh(n, w), f"contact.slip_rate_regularisation_m_s={eps}")
            for n, w in ((16, 2), (16, 4)) for eps in (1e-4, 1e-5, 1e-6)}

#: meshes and rules for the shipped default (the cases that ran before the scene's rule
#: changed to 5 x 5 Gauss pin the 3 x 3 they ran with, so their names stay true)
G4 = quad("gauss", 4)
CANDIDATES = {
    "old-default": OLD_DEFAULT,
    "shipped": (),                                                   # the scene as shipped
    "half-16x2": (*HALF, *UMF, *G4),
    "half-16x4": (*HALF, *UMF, *mesh(16, 4), *G4),
    "half-16x4-lob4": (*HALF, *UMF, *mesh(16, 4), *quad("gauss_lobatto", 4)),
    "half-12x4-g2-lob4": (*HALF, *UMF, *mesh(12, 4), "mesh.x_grading=2.0", *quad("gauss_lobatto", 4)),
    "half-16x4-g2-lob4": (*HALF, *UMF, *mesh(16, 4), "mesh.x_grading=2.0", *quad("gauss_lobatto", 4)),
    "half-16x4x2x1-lob4": (*HALF, *UMF, *mesh(16, 4, 2, 1), *quad("gauss_lobatto", 4)),
    "half-24x6-lob4": (*HALF, *UMF, *mesh(24, 6), *quad("gauss_lobatto", 4)),
    "half-12x4-g2": (*HALF, *UMF, *mesh(12, 4), "mesh.x_grading=2.0", *G4),
    "half-12x4-g2-g8": (*HALF, *UMF, *mesh(12, 4), "mesh.x_grading=2.0", *quad("gauss", 8)),
    "half-16x4-g2": (*HALF, *UMF, *mesh(16, 4), "mesh.x_grading=2.0", *G4),
    "half-10x4-g2-lob4": (*HALF, *UMF, *mesh(10, 4), "mesh.x_grading=2.0", *quad("gauss_lobatto", 4)),
    "half-12x6-g2-lob4": (*HALF, *UMF, *mesh(12, 6), "mesh.x_grading=2.0", *quad("gauss_lobatto", 4)),
    "half-16x2-lob4": (*HALF, *UMF, *quad("gauss_lobatto", 4)),
    "half-16x2-lob3": (*HALF, *UMF, *quad("gauss_lobatto", 3)),
    "half-16x2-g2-lob4": (*HALF, *UMF, "mesh.x_grading=2.0", *quad("gauss_lobatto", 4)),
    "half-12x2-g2-lob4": (*HALF, *UMF, *mesh(12, 2), "mesh.x_grading=2.0", *quad("gauss_lobatto", 4)),
    "half-16x4-lob3": (*HALF, *UMF, *mesh(16, 4), *quad("gauss_lobatto", 3)),
    "half-12x2-g8": (*HALF, *UMF, *mesh(12, 2), *quad("gauss", 8)),
    "half-12x2-g2-g8": (*HALF, *UMF, *mesh(12, 2), "mesh.x_grading=2.0", *quad("gauss", 8)),
    "half-16x2-g2-g8": (*HALF, *UMF, "mesh.x_grading=2.0", *quad("gauss", 8)),
    "half-12x6-g8": (*HALF, *UMF, *mesh(12, 6), *quad("gauss", 8)),
    "half-12x6x2x2-g8": (*HALF, *UMF, *mesh(12, 6, 2, 2), *quad("gauss", 8)),
    "half-16x6-g8": (*HALF, *UMF, *mesh(16, 6), *quad("gauss", 8)),
    "half-16x10-g8": (*HALF, *UMF, *mesh(16, 10), *quad("gauss", 8)),
}

#: the datasets' fidelity ``resolved`` refined one direction at a time (issue 23, twelfth session):
#: C3 at the fidelity ladder's reference step 0.005 s (the shipped 1/720 s moves the travel 0.2 %).
#: The layers are the divisions through each layer's thickness, the patch the 2 mm tip zone (x)
#: and the 3 <= z <= 5 mm rim band (z), 0.5 mm elements at ``resolved``; ``level1`` doubles every
#: division (the fidelity ladder's reference, 34,700 dofs: run it with --reference-ranks 2).
REFINE_DT = ("time.dt_max_s=0.005", "time.dt_initial_s=0.001")


def layers(n: int) -> tuple:
    return (f"mesh.n_active={n}", f"mesh.n_passive={n}")


def tip_rim(tip: int, rim: int) -> tuple:
    return (f"mesh.tip_zone_divisions={tip}", f"mesh.rim_band_divisions={rim}")


def refined(*overrides) -> tuple:
    return (*RESOLVED, *REFINE_DT, *overrides)


REFINE_BASE = "resolved-5ms"
REFINE = {REFINE_BASE: refined(),
          "inplane2": refined("mesh.n_length=16", "mesh.n_width=4"),
          "patch2": refined(*tip_rim(8, 8)),
          **{f"layers{n}": refined(*layers(n)) for n in (2, 4, 8)},
          "layers2-patch2": refined(*layers(2), *tip_rim(8, 8)),
          "layers4-patch2": refined(*layers(4), *tip_rim(8, 8)),
          "layers2-tip2-rim4": refined(*layers(2), *tip_rim(8, 16)),
          # two elements through the active stack, four through the passive layer graded 4:1 toward
          # the underside (0.11 mm on the face that touches the coin; layers8 has 0.125 mm there)
          "graded-a2-p4": refined("mesh.n_active=2", "mesh.n_passive=4", "mesh.underside_grading=4.0"),
          "level1": refined("mesh.level=1")}
#: the layers ladder (one, two, four, eight elements per layer; refinement ratio 2)
REFINE_LAYERS = (REFINE_BASE, "layers2", "layers4", "layers8")

#: the finest mesh's pause (issue 23): ``layers4-patch2`` stops the coin for 25 ms at 357-367 V
#: while its contact line jumps inward across the rim band's node line z = 3.75 mm; no coarser
#: mesh stops. The checks, each at twice the step (0.01 s, which moves the travel 0.3 %): the
#: case itself, its rim band shifted by half an element (node lines at 3.625 / 3.875 mm), and a
#: coarser contact rule (degree 12, 7 x 7 points per facet, against 11 x 11); and the cheaper
#: underside grading of ``graded-a2-p4`` with the 0.25 mm patch, and with the rim band alone at
#: 0.25 mm (the tip zone at 0.5 mm).
PAUSE_BASE = "l4p2-dt10ms"
_L4P2_10MS = (*REFINE["layers4-patch2"], "time.dt_max_s=0.01")
PAUSE = {PAUSE_BASE: _L4P2_10MS,
         "l4p2-dt10ms-shift": (*_L4P2_10MS, "mesh.rim_band_m=[0.003125,0.005125]"),
         "l4p2-dt10ms-rule12": (*_L4P2_10MS, "contact.quadrature_degree=12"),
         "graded-p2-dt10ms": (*REFINE["graded-a2-p4"], *tip_rim(8, 8), "time.dt_max_s=0.01"),
         "graded-rim2-dt10ms": (*REFINE["graded-a2-p4"], *tip_rim(4, 8), "time.dt_max_s=0.01"),
         # the two ladders through graded-p2-dt10ms: the tip zone along x (0.5 / 0.25 / 0.125 mm,
         # with graded-rim2-dt10ms), and the underside (four / eight graded passive elements). The
         # eight-element underside stalled here at t = 0.8634 s (its Newton solve diverging through
         # cut-backs down to 0.9 us where the coin stops; docs/fem_accuracy.md): run it with --cases
         # only where hours of creeping steps can be afforded
         "graded-tip16-dt10ms": (*REFINE["graded-a2-p4"], *tip_rim(16, 8), "time.dt_max_s=0.01"),
         "graded-p8-p2-dt10ms": refined("mesh.n_active=2", "mesh.n_passive=8", "mesh.underside_grading=4.0",
                                        *tip_rim(8, 8), "time.dt_max_s=0.01")}

STUDIES = {"reference": REFERENCE, "patch-soft": PATCH_SOFT, "patch-rule": PATCH_RULE, "patch-fine": PATCH_FINE, "patch-penalty": PATCH_PENALTY, "uniform": UNIFORM, "levels": LEVELS, "dt": DT, "quadrature": QUADRATURE, "friction": FRICTION, "candidates": CANDIDATES, "shipped": SHIPPED,
           "refine": REFINE, "pause": PAUSE}


def mpirun_env() -> dict:
    """The environment for ``mpirun`` here (as root in a container, more ranks than cores allowed)."""
    return dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
                OMPI_MCA_rmaps_base_oversubscribe="1")


def solve(out: Path, name: str, overrides, extra=(), ranks: int = 1) -> Path:
    """Run one case unless its dataset exists; returns the dataset path. ``ranks`` > 1 splits
    the one mesh over MPI ranks (the solver then factorises with MUMPS, whatever the scene's
    serial package: the resolved scene, and so the resume check, is the same)."""
    path = out / name / "C3.nc"
    if dataset.is_complete(path, resolved_scene((*overrides, *extra))):
        return path               # made with this case's resolved scene: a changed default re-runs it
    cmd = [sys.executable, "-m", "deapull.workflows", "solve", "--scene", "coin_pull", "--setup", "C3",
           "--out", str(out / name)]
    env = None
    if ranks > 1:
        cmd, env = ["mpirun", "-n", str(ranks), *cmd], mpirun_env()
    for o in (*overrides, *extra):
        cmd += ["--set", o]
    log.info("%s: %s", name, " ".join(cmd[cmd.index("-m") + 2:]))
    (out / name).mkdir(parents=True, exist_ok=True)
    solve_log = out / name / "solve.log"      # the solve's own progress and log, as it runs
    log.info("%s: follow it with: tail -f %s", name, solve_log)
    start = time.perf_counter()
    with open(solve_log, "w") as stream:
        proc = subprocess.run(cmd, stdout=stream, stderr=subprocess.STDOUT, text=True, env=env)
    if proc.returncode != 0:
        raise RuntimeError(f"case {name} failed ({proc.returncode}):\n{solve_log.read_text()[-2000:]}")
    log.info("%s: done in %.0f s", name, time.perf_counter() - start)
    return path


def resolved_scene(overrides) -> str:
    """The case's resolved scene as TOML (what its dataset's ``scene_toml`` records)."""
    return scenes.load("coin_pull", setup="C3", overrides=overrides).to_toml()


def columns(path: Path) -> dataset.Run:
    return dataset.read(path, ("t", "x", "newton_iterations", "penetration_m"),
                        optional=("penetration_qp_m", "n_contact", "table_penetration_m"))


#: safety factor of the grid convergence index over three grids (Roache; Celik et al. 2008)
GCI_SAFETY = 1.25


def richardson(travels, ratios):
    """Observed order p, extrapolated value and the finest level's error bound from three
    levels h1 > h2 > h3 with refinement ratios r21 = h1/h2, r32 = h2/h3 (unequal ratios allowed;
    the GCI procedure of Celik et al. (2008), J. Fluids Eng. 130).

    The bound is the grid convergence index of the finest level, GCI_SAFETY × |f_ext − f3|.
    When the three levels do not converge monotonically (the differences change sign or one
    is zero), or no order in (0, 20] fits them, there is no order: p is NaN, the estimate is
    f3 and the bound the larger of the two differences.
    """
    f1, f2, f3 = travels
    r21, r32 = ratios
    e21, e32 = f2 - f1, f3 - f2
    if e21 == 0 or e32 == 0 or e21 * e32 < 0:
        return float("nan"), f3, max(abs(e21), abs(e32))
    # f_i = f + C h_i^p gives e21 / e32 = r32^p (r21^p − 1) / (r32^p − 1): solve for p by bisection
    def g(p):
        return math.log(abs(e21 / e32)) - p * math.log(r32) - math.log((r21 ** p - 1) / (r32 ** p - 1))
    lo, hi = 1e-3, 20.0
    if g(lo) * g(hi) > 0:
        return float("nan"), f3, max(abs(e21), abs(e32))
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if g(lo) * g(mid) > 0 else (lo, mid)
    p = 0.5 * (lo + hi)
    extrap = f3 + e32 / (r32 ** p - 1)
    return p, extrap, GCI_SAFETY * abs(extrap - f3)


def reference_estimate(travels, ratios, penalty_pair) -> dict:
    """The reference travel and its stated bound from the ladder's three ``travels`` (coarse to
    fine, refinement ``ratios``) and the ``penalty_pair`` (the 0.5 mm level's travel at x 100 and
    at the reference penalty).

    Mesh share: with an observed order, the GCI of :func:`richardson`; without one (oscillating
    levels), the two finest levels' difference; the three levels' spread is kept beside it. Penalty
    share: the travel's penalty error goes as 1/k_n, so the x ``REFERENCE_TIMES`` level keeps
    (1/1000) / (1/100 - 1/1000) = 1/9 of the pair's difference. The bound is their sum.
    """
    p, extrap, gci = richardson(travels, ratios)
    if math.isfinite(p):
        mesh_bound, how = gci, f"observed order {p:.2f}, GCI"
    else:
        extrap, mesh_bound = travels[-1], abs(travels[-1] - travels[-2])
        how = "no observed order (the levels oscillate): the two finest levels' difference"
    k = 1.0 / REFERENCE_TIMES
    penalty_bound = abs(penalty_pair[1] - penalty_pair[0]) * k / (1.0 / 100 - k)
    return {"observed_order": p, "travel_extrapolated_m": extrap, "mesh_bound_m": mesh_bound,
            "mesh_bound_is": how, "three_level_spread_m": max(travels) - min(travels),
            "penalty_bound_m": penalty_bound, "travel_error_bound_m": mesh_bound + penalty_bound}


def reference_summary(out: Path) -> dict:
    runs = [columns(out / n / "C3.nc") for n in REFERENCE_ORDER]
    travels = [float(np.max(np.abs(r.columns["x"]))) for r in runs]
    pair = [float(np.max(np.abs(columns(out / n / "C3.nc").columns["x"]))) for n in PENALTY_PAIR]
    est = reference_estimate(travels, REFERENCE_RATIOS, pair)
    extrap, bound = est["travel_extrapolated_m"], est["travel_error_bound_m"]
    fine = runs[-1]
    t = fine.columns["t"]
    mae = [float(np.mean(np.abs(np.interp(t, r.columns["t"], r.columns["x"]) - fine.columns["x"])))
           for r in runs[:-1]]
    dofs = [int(r.attrs["mesh_dofs"]) for r in runs]
    eps = float(fine.attrs["contact_slip_rate_reg_m_s"])
    active = [int(np.median(r.columns["n_contact"])) for r in runs]
    what = "Richardson travel" if math.isfinite(est["observed_order"]) else "finest level"
    label = (f"{what} of the resolved-patch ladder {' / '.join(f'{h:g}' for h in PATCH_SIZES_MM)} mm at x "
             f"{REFERENCE_TIMES} the shipped coin penalty (coin_pull C3 with the table, half model, dofs "
             f"{' / '.join(f'{d:,}' for d in dofs)}; 9 x 9 Gauss contact points, {' / '.join(map(str, active))} "
             f"active at the median step; 1/720 s, eps_v {eps:g} m/s); bound: mesh ({est['mesh_bound_is']}) "
             f"+ penalty (1/k_n from x 100 -> x {REFERENCE_TIMES}); x(t) of the finest level")
    return {"cases": list(REFERENCE_ORDER), "travel_m": travels, "dofs": dofs, "median_active_contact_points": active,
            "wall_s": [float(r.attrs["wall_time_total_s"]) for r in runs], **est,
            "penalty_pair": list(PENALTY_PAIR), "penalty_pair_travel_m": pair,
            "travel_error_bound_rel": bound / extrap, "x_mae_vs_finest_m": mae,
            "label": label,
            "travel_ref_m": extrap,
            "error_bound_rel": bound / extrap,
            "slip_rate_reg_m_s": eps,
            "finest": str(out / REFERENCE_ORDER[-1] / "C3.nc")}


def compare(out: Path, names, ref: dict, fine: dataset.Run) -> list[dict]:
    """One row per case: cost, travel error against the reference's travel, x(t) MAE against
    the finest level's x(t) (``fine``), penetrations and active contact points."""
    t_ref, x_ref = fine.columns["t"], fine.columns["x"]
    travel_ref = ref["travel_extrapolated_m"]
    rows = []
    for name in names:
        r = columns(out / name / "C3.nc")
        x = r.columns["x"]
        travel = float(np.max(np.abs(x)))
        mae = float(np.mean(np.abs(np.interp(t_ref, r.columns["t"], x) - x_ref)))
        qp, nc = r.columns.get("penetration_qp_m"), r.columns.get("n_contact")
        rows.append({"case": name, "dofs": int(r.attrs["mesh_dofs"]), "points": len(x),
                     "wall_s": float(r.attrs["wall_time_total_s"]),
                     "newton_its": int(np.sum(r.columns["newton_iterations"])), "travel_mm": travel * 1e3,
                     "travel_err_pct": 100 * (travel / travel_ref - 1), "x_mae_pct": 100 * mae / travel_ref,
                     "active_points": int(np.median(nc)) if nc is not None else -1,
                     "pen_nodes_um": 1e6 * float(np.max(r.columns["penetration_m"])),
                     "pen_qp_um": 1e6 * float(np.max(qp)) if qp is not None else float("nan")})
    return rows


TABLE = (("case", "case", ""), ("dofs", "dofs", "d"), ("points", "points", "d"), ("wall s", "wall_s", ".1f"),
         ("Newton its", "newton_its", "d"), ("travel mm", "travel_mm", ".4f"), ("travel err %", "travel_err_pct", "+.2f"),
         ("x(t) MAE %", "x_mae_pct", ".2f"), ("contact points (median)", "active_points", "d"),
         ("max pen. nodes µm", "pen_nodes_um", ".2f"), ("max pen. points µm", "pen_qp_um", ".2f"))


#: measured runs refined in directions the reference ladder leaves as shipped (the layers, the
#: underside); committed beside the reference (docs/fem_accuracy.md, twelfth and sixteenth sessions)
BEYOND_THE_LADDER = "beyond_the_ladder.json"
COMMITTED_REFERENCE = Path(__file__).resolve().parents[1] / "bench" / "reference"


def load_reference(folder: Path) -> dict:
    """``folder/reference.json`` with the runs refined beyond its ladder: see
    :func:`with_beyond_the_ladder`."""
    folder = Path(folder)
    return with_beyond_the_ladder(json.loads((folder / "reference.json").read_text()), folder)


def with_beyond_the_ladder(ref: dict, folder: Path | None = None) -> dict:
    """``ref`` with ``beyond_the_ladder`` (the runs refined in directions its ladder leaves as
    shipped) when it has none: ``folder``'s own ``beyond_the_ladder.json``, else the committed
    one. Every reference that ``--study reference`` builds refines the same directions, so the
    committed runs apply to it; a reference written before they existed gets them too."""
    if "beyond_the_ladder" in ref:
        return ref
    for source in ([Path(folder) / BEYOND_THE_LADDER] if folder else []) + [COMMITTED_REFERENCE / BEYOND_THE_LADDER]:
        if source.is_file():
            return {**ref, "beyond_the_ladder": json.loads(source.read_text())}
    return ref


def ladder_gap(ref: dict) -> dict | None:
    """How far the runs refined beyond the ladder move the travel, each against ``resolved`` at
    its own time step: ``{"least_rel", "most_rel", "most_refines", "finest_bound_rel", "runs"}``
    (relative changes, negative = less travel), or None when the reference carries no such runs.

    The ladder's bound covers the directions it refines; ``least_rel`` is a measured lower limit
    on how far the reference's travel is from a mesh refined in every direction, and no bound
    smaller than it can be stated."""
    beyond = (ref.get("beyond_the_ladder") or {}).get("runs") or []
    if not beyond:
        return None
    changes = [(r["travel_m"] / r["resolved_same_step_m"] - 1, r) for r in beyond]
    least = min(changes, key=lambda c: abs(c[0]))
    most = max(changes, key=lambda c: abs(c[0]))
    finest = (ref.get("beyond_the_ladder") or {}).get("finest_ladder") or {}
    return {"least_rel": least[0], "most_rel": most[0], "most_refines": most[1]["refines"],
            "finest_bound_rel": finest.get("bound_rel"), "runs": changes}


def ladder_gap_lines(ref: dict) -> list[str]:
    """The lines under the ladder's table that say what its bound leaves out (none without runs)."""
    gap = ladder_gap(ref)
    if gap is None:
        return []
    bound = ref.get("error_bound_rel")
    lines = ["beyond the ladder (directions it leaves as shipped), each against resolved at the same step:"]
    for change, r in gap["runs"]:
        lines.append(f"  {r['refines']:s}: {r['dofs']:,d} dofs, dt {r['dt_max_s']:g} s, travel "
                     f"{1e3 * r['travel_m']:.4f} mm, {100 * change:+.1f} %")
    finest = gap["finest_bound_rel"]
    lines.append(f"so the ladder's ± {100 * bound:.2f} % covers the tip zone and the penalty only: refining the "
                 f"layers and the underside moves the travel {100 * gap['least_rel']:+.1f} % to "
                 f"{100 * gap['most_rel']:+.1f} %"
                 + (f", and those meshes have no observed order (their own ladder's bound {100 * finest:.1f} %)"
                    if finest is not None else "")
                 + f"; stated bound on the reference: none ≤ 1 % (goal). It has resolved's layers, so its own "
                   f"error is likely {100 * abs(gap['least_rel']):.1f} % or more")
    return lines


def ladder_table(ref: dict) -> str:
    """The reference's convergence table (its levels: dofs, active contact points, travel, the
    change from the level before, wall time) and its order and bound, as text."""
    travels = ref.get("travel_m") or []
    active = ref.get("median_active_contact_points") or [None] * len(travels)
    lines = [f"{'reference level':24s} {'dofs':>7s} {'contact pts':>11s} {'travel mm':>10s} {'vs previous':>11s} "
             f"{'wall s':>8s}"]
    for i, (case, dofs, pts, travel, wall) in enumerate(zip(ref["cases"], ref["dofs"], active, travels, ref["wall_s"])):
        change = f"{100 * (travel / travels[i - 1] - 1):+10.3f}%" if i else f"{'':>11s}"
        lines.append(f"{case:24s} {dofs:7,d} {pts if pts is not None else '-':>11} {1e3 * travel:10.4f} {change} "
                     f"{wall:8.0f}")
    p = ref.get("observed_order", float("nan"))
    what = f"observed order {p:.2f}, Richardson travel" if math.isfinite(p) else "no observed order; finest level"
    lines.append(f"{what} {1e3 * ref['travel_extrapolated_m']:.4f} mm ± {1e3 * ref['travel_error_bound_m']:.4f} mm "
                 f"({100 * ref['travel_error_bound_rel']:.2f} % of it; goal: a stated bound ≤ 1 %)")
    if "mesh_bound_m" in ref:
        travel = ref["travel_extrapolated_m"]
        lines.append(f"  the bound's parts: mesh {100 * ref['mesh_bound_m'] / travel:.2f} % ({ref['mesh_bound_is']}), "
                     f"penalty {100 * ref['penalty_bound_m'] / travel:.2f} % ({' vs '.join(ref['penalty_pair'])}); "
                     f"the three levels span {100 * ref['three_level_spread_m'] / travel:.2f} %")
    lines += ladder_gap_lines(ref)
    return "\n".join(lines)


REFINE_TABLE = (("case", "case", ""), ("dofs", "dofs", "d"), ("wall s", "wall_s", ".0f"),
                ("travel mm", "travel_mm", ".4f"), (f"vs {REFINE_BASE} %", "vs_base_pct", "+.2f"),
                ("vs finest %", "vs_finest_pct", "+.2f"), ("x(t) vs finest %", "x_mae_finest_pct", ".2f"),
                ("x(0.9 s) mm", "x_09_mm", ".4f"), ("stroke mm", "stroke_mm", ".4f"),
                ("contact points (median)", "active_points", "d"), ("max pen. points µm", "pen_qp_um", ".2f"))


def refine_summary(out: Path) -> tuple[list[dict], list[str]]:
    """The ``refine`` study against its own cases: every case of it complete under ``out`` (run
    now or before), its travel, the change from ``resolved`` at the same step, and its travel
    and x(t) (MAE, % of the finest travel) against the finest case there (the most dofs); |x| at
    0.9 s (the meshes part in the ramp's last 0.1 s), the DEA's stroke |tip_ux| at the end and the
    deepest contact point's penetration (the penalty's peak pressure over k_n: it grows as the
    meshes resolve the rim's indentation). Then the layers ladder (one, two, four, eight elements per
    layer) through :func:`richardson`, each three consecutive levels on their own: an order
    that the first three do not share is not an asymptotic one, and the lines say so."""
    names = [n for n in REFINE if dataset.is_complete(out / n / "C3.nc", resolved_scene(REFINE[n]))]
    runs = {n: dataset.read(out / n / "C3.nc", ("t", "x", "tip_ux"), optional=("n_contact", "penetration_qp_m"))
            for n in names}
    if not runs:
        return [], ["refine: no case of the study is complete under " + str(out)]
    travel = {n: float(np.max(np.abs(r.columns["x"]))) for n, r in runs.items()}
    finest = max(names, key=lambda n: int(runs[n].attrs["mesh_dofs"]))
    t_f, x_f = runs[finest].columns["t"], runs[finest].columns["x"]
    rows = []
    for n in names:
        r = runs[n]
        nc = r.columns.get("n_contact")
        mae = float(np.mean(np.abs(np.interp(t_f, r.columns["t"], r.columns["x"]) - x_f)))
        rows.append({"case": n, "dofs": int(r.attrs["mesh_dofs"]), "wall_s": float(r.attrs["wall_time_total_s"]),
                     "travel_mm": 1e3 * travel[n],
                     "vs_base_pct": 100 * (travel[n] / travel[REFINE_BASE] - 1) if REFINE_BASE in travel else math.nan,
                     "vs_finest_pct": 100 * (travel[n] / travel[finest] - 1),
                     "x_mae_finest_pct": 100 * mae / travel[finest],
                     "x_09_mm": 1e3 * abs(float(np.interp(0.9, r.columns["t"], r.columns["x"]))),
                     "stroke_mm": 1e3 * abs(float(r.columns["tip_ux"][-1])),
                     "active_points": int(np.median(nc)) if nc is not None else -1,
                     "pen_qp_um": 1e6 * float(np.max(r.columns.get("penetration_qp_m", np.nan)))})
    lines = [f"finest case: {finest} ({int(runs[finest].attrs['mesh_dofs']):,} dofs), travel "
             f"{1e3 * travel[finest]:.4f} mm"]
    ladder_travels = [travel.get(n) for n in REFINE_LAYERS]
    for i in range(len(REFINE_LAYERS) - 2):
        triple = ladder_travels[i:i + 3]
        label = " / ".join(REFINE_LAYERS[i:i + 3])
        if any(f is None for f in triple):
            continue
        lines.append(ladder_line(f"layers {label}", triple)[0])
    return rows, lines


def ladder_line(label: str, triple) -> tuple[str, float, float]:
    """Three levels' travels (refinement ratio 2) through :func:`richardson`: a line that gives the
    observed order, the Richardson travel and its bound, or says that there is no order; and the
    extrapolated travel and the bound (without an order: the finest travel, the larger step)."""
    p, extrap, bound = richardson(triple, (2.0, 2.0))
    steps = f"the steps {1e3 * (triple[1] - triple[0]):+.4f}, {1e3 * (triple[2] - triple[1]):+.4f} mm"
    if math.isfinite(p):
        return (f"{label} ({steps}): observed order {p:.2f}, Richardson travel {1e3 * extrap:.4f} mm "
                f"± {1e3 * bound:.4f} mm ({100 * bound / extrap:.2f} %)"), extrap, bound
    return f"{label}: no observed order ({steps} do not shrink geometrically)", extrap, bound


PAUSE_TABLE = (("case", "case", ""), ("dofs", "dofs", "d"), ("travel mm", "travel_mm", ".4f"),
               (f"vs {PAUSE_BASE} %", "vs_base_pct", "+.2f"), ("stops", "stops", "d"),
               ("stopped s", "stopped", ""), ("contact abs(z) across it mm", "contact_z_mm", ""),
               ("contact points (min in the slide)", "min_points", "d"))


def stops(t, x, stick, contact_abs_z=None) -> list[dict]:
    """The coin's stops in the slide: maximal runs of records with ``stick`` = 1 after the first
    sliding record (``stick`` = 0 and the coin moved), up to the last sliding one (a coin standing
    at the end has stopped sliding, not paused). Each stop: its first and last record's time and,
    when given, the contact centre's abs(z) on the last sliding record before it and the first
    after it."""
    t, x, stick = (np.asarray(a, dtype=float) for a in (t, x, stick))
    sliding = np.flatnonzero((stick == 0) & (np.abs(x) > 0))
    if sliding.size == 0:
        return []
    out, i = [], sliding[0]
    while i <= sliding[-1]:
        if stick[i] == 1:
            j = i
            while stick[j + 1] == 1:
                j += 1
            stop = {"t0": float(t[i]), "t1": float(t[j])}
            if contact_abs_z is not None:
                stop["z_before"], stop["z_after"] = float(contact_abs_z[i - 1]), float(contact_abs_z[j + 1])
            out.append(stop)
            i = j + 1
        i += 1
    return out


def pause_summary(out: Path) -> list[dict]:
    """The ``pause`` study's own table: each complete case's travel against ``PAUSE_BASE``, the
    coin's stops in the slide (:func:`stops`) with the contact line's abs(z) across the first one,
    and the fewest contact points while the coin slides."""
    rows, base = [], None
    for name in PAUSE:
        if not dataset.is_complete(out / name / "C3.nc", resolved_scene(PAUSE[name])):
            continue
        r = dataset.read(out / name / "C3.nc", ("t", "x", "stick"), optional=("n_contact", "contact_abs_z"))
        c = r.columns
        travel = float(np.max(np.abs(c["x"])))
        base = travel if name == PAUSE_BASE else base
        found = stops(c["t"], c["x"], c["stick"], contact_abs_z=c.get("contact_abs_z"))
        slide = (c["stick"] == 0) & (np.abs(c["x"]) > 0)
        nc = c.get("n_contact")
        z = [f"{1e3 * s['z_before']:.3f} → {1e3 * s['z_after']:.3f}" for s in found if "z_before" in s]
        rows.append({"case": name, "dofs": int(r.attrs["mesh_dofs"]), "travel_mm": 1e3 * travel,
                     "vs_base_pct": 100 * (travel / base - 1) if base else math.nan, "stops": len(found),
                     "stopped": "; ".join(f"{s['t0']:.3f}–{s['t1']:.3f}" for s in found) or "–",
                     "contact_z_mm": z[0] if z else "–",
                     "min_points": int(np.min(nc[slide])) if nc is not None and slide.any() else -1})
    return rows


#: the pause study's ladder along the tip zone (x): 0.5 / 0.25 / 0.125 mm elements over the 2 mm at
#: the free end, on ``graded-a2-p4``'s underside with the 0.25 mm rim band (refinement ratio 2)
PAUSE_TIP_LADDER = ("graded-rim2-dt10ms", "graded-p2-dt10ms", "graded-tip16-dt10ms")
#: and the underside's pair through its middle level: four / eight graded passive elements
PAUSE_UNDERSIDE_PAIR = ("graded-p2-dt10ms", "graded-p8-p2-dt10ms")
#: the contact rule's pair: 11 x 11 / 7 x 7 points per facet on ``layers4-patch2``
PAUSE_RULE_PAIR = (PAUSE_BASE, "l4p2-dt10ms-rule12")


def pause_ladders(rows: list[dict]) -> list[str]:
    """The pause study's convergence lines from :func:`pause_summary`'s ``rows`` (the complete
    cases): the tip-zone ladder (``PAUSE_TIP_LADDER``) through
    :func:`richardson`, the underside's and the contact rule's two-level changes, and, when all
    three are complete, a stated bound on the tip ladder's Richardson travel: its GCI (without an
    observed order: the larger step, on the finest travel) plus the whole two-level change of the
    underside and of the rule (no order is assumed for those, so each counts in full)."""
    travel = {r["case"]: 1e-3 * r["travel_mm"] for r in rows}
    lines, parts = [], {}
    if all(n in travel for n in PAUSE_TIP_LADDER):
        line, ref, bound = ladder_line("tip zone 0.5 / 0.25 / 0.125 mm", [travel[n] for n in PAUSE_TIP_LADDER])
        lines.append(line)
        parts["tip zone"] = bound
    for what, (a, b) in (("underside", PAUSE_UNDERSIDE_PAIR), ("contact rule", PAUSE_RULE_PAIR)):
        if a in travel and b in travel:
            change = travel[b] - travel[a]
            lines.append(f"{what}: {b} against {a}: {1e3 * change:+.4f} mm ({100 * change / travel[a]:+.2f} %)")
            parts[f"{what} (two levels)"] = abs(change)
    if len(parts) == 3:
        total = sum(parts.values())
        lines.append(f"stated bound on {1e3 * ref:.4f} mm: ± {1e3 * total:.4f} mm ({100 * total / ref:.2f} %; goal ≤ 1 %) = "
                     + " + ".join(f"{what} {100 * v / ref:.2f} %" for what, v in parts.items()))
    return lines


def run_studies(studies, out: Path, reference: Path, cases=(), reference_ranks: int = 1) -> int:
    """Run the studies' missing cases (resumes), then print the reference's convergence table
    and every study's comparison against it. With ``reference`` among the studies the reference
    is rebuilt from ``out`` (and written to ``out/reference/``, the folder ``bench/reference``
    ships); otherwise ``reference`` (reference.json + C3_reference.nc) is the reference."""
    chosen = {study: list(cases) or list(STUDIES[study]) for study in studies}
    if "reference" not in studies and not (reference / "reference.json").is_file():
        raise InputError(f"--reference {reference}: no reference.json there (the committed one is bench/reference/ "
                         "in the source checkout; --study reference rebuilds it)")
    for study in studies:
        unknown = [c for c in chosen[study] if c not in STUDIES[study]]
        if unknown:
            raise InputError(f"--cases: {', '.join(unknown)} not in study {study!r} (its cases: "
                             f"{', '.join(STUDIES[study])})")
    for study in studies:
        for name in chosen[study]:
            solve(out, name, STUDIES[study][name],
                  ranks=reference_ranks if study in ("reference", "refine", "pause") else 1)
    if "reference" in studies:
        missing = [n for n in REFERENCE_ORDER
                   if not dataset.is_complete(out / n / "C3.nc", resolved_scene(REFERENCE[n]))]
        if missing:
            print(f"reference incomplete: {', '.join(missing)} missing; run --study reference")
            return 1
        ref = reference_summary(out)
        write_json(out / "reference.json", ref, indent=2)
        reference = out / "reference"
        write_json(reference / "reference.json", ref, indent=2)
        atomic_write(reference / "C3_reference.nc", lambda tmp: shutil.copyfile(ref["finest"], tmp))
    ref = load_reference(reference)
    fine = columns(reference / "C3_reference.nc")
    print(f"reference: {ref['label']}")
    print(ladder_table(ref))
    for study in studies:
        rows = compare(out, chosen[study], ref, fine)
        write_csv(out / f"{study}.csv", rows, [k for _, k, _ in TABLE])
        table = markdown_table(rows, TABLE)
        write_text(out / f"{study}.md", table + "\n")
        print(f"\n{study} (errors against the reference travel {1e3 * ref['travel_extrapolated_m']:.4f} mm and "
              f"the finest level's x(t))\n{table}")
        if study == "refine":
            rows, lines = refine_summary(out)
            if rows:
                write_csv(out / "refine-own.csv", rows, [k for _, k, _ in REFINE_TABLE])
                table = markdown_table(rows, REFINE_TABLE)
                write_text(out / "refine-own.md", table + "\n\n" + "\n".join(f"- {x}" for x in lines) + "\n")
                print(f"\nrefine against its own finest case\n{table}")
            print("\n".join(lines))
        if study == "pause":
            rows = pause_summary(out)
            if rows:
                table = markdown_table(rows, PAUSE_TABLE)
                write_csv(out / "pause-own.csv", rows, [k for _, k, _ in PAUSE_TABLE])
                lines = pause_ladders(rows)
                write_text(out / "pause-own.md", table + "\n\n" + "".join(f"- {x}\n" for x in lines))
                print(f"\nthe coin's stops in the slide (pause)\n{table}")
                print("\n".join(lines))
    return 0


def add_arguments(ap) -> None:
    ap.add_argument("--study", default="shipped",
                    help=f"comma-separated studies, or all: {', '.join(STUDIES)} (default shipped: the scene file "
                         "and the resolved fidelity, each with its rule doubled, against the committed reference; "
                         "four runs, ~15 min on one core)")
    ap.add_argument("--out", default="out/fem_study", help="one folder per case; CSV and Markdown per study")
    ap.add_argument("--reference", default="bench/reference",
                    help="folder with reference.json and C3_reference.nc (default: the committed one)")
    ap.add_argument("--cases", default="", help="comma-separated subset of the study's cases")
    ap.add_argument("--reference-ranks", type=int, default=1,
                    help="MPI ranks for each reference level and each refine case (> 1: one mesh split over "
                         "ranks, MUMPS); other studies run on one core")


def studies_from(arg: str) -> list[str]:
    """The ``--study`` list, checked before any run."""
    studies = list(STUDIES) if arg == "all" else [s for s in arg.split(",") if s]
    unknown = [s for s in studies if s not in STUDIES]
    if unknown or not studies:
        raise InputError(f"--study {arg!r}: unknown {', '.join(unknown) or 'empty'}; allowed: "
                         f"{', '.join(STUDIES)} or all")
    return studies


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_arguments(ap)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s", datefmt="%H:%M:%S")
    try:
        studies = studies_from(args.study)
        return run_studies(studies, Path(args.out), Path(args.reference), [c for c in args.cases.split(",") if c],
                           args.reference_ranks)
    except InputError as e:
        ap.error(str(e))


if __name__ == "__main__":
    raise SystemExit(main())
