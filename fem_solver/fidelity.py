"""Error against run time of the FEM: the fidelity ladder (``deapull fidelity``).

A *rung* is one FEM run of the same scene and setup with one discretisation: element
(P1 / P2 tetrahedra, Q2 hexahedra), formulation (mixed u–p or pure displacement),
resolution (coarse, the shipped mesh, finer in-plane, one or two uniform refinements)
and largest time step. Every rung is compared with the *reference rung* (the finest
affordable run: Q2–Q1 hexahedra refined once, half the time step): MAE of the coin
position x(t) and of the pressing force Fy(t), both interpolated onto the reference's
t, and the error in coin travel. Pure displacement needs ν < 0.5, so those rungs use
ν = 0.49; their error includes that modelling change (rung ``hex-Q2-mixed-L0-nu049``
measures it alone).

Resolutions and steps are relative to the scene as loaded (with ``--set``), so a tiny
base mesh gives a tiny ladder. ``rungs = "full"`` keeps the scene's protocol and steps
(coin_pull: 1 s, dt_max 1/720 s, ≥ 720 points). ``"quick"`` keeps the 1 s protocol but
makes the ladder's base step end/100 (0.01 s, ~100 points; the flow is quasi-static, so
this moves the coin travel by ~0.2 %) and adds the shipped discretisation at the shipped
step as its own rung, so the default is still placed on the ladder.

This module also holds the study harness that :mod:`fem_solver.stability` reuses:
cases spread over MPI rank groups (``comm.Split``), one result JSON per case written
atomically and skipped when present, so an interrupted study resumes.
"""
from __future__ import annotations

import json
import logging
import math
import os
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from fem_solver.parallel import idle_barrier, initialise_petsc
from workflows import scene as scenes
from workflows.errors import InputError

log = logging.getLogger(__name__)


# --- the study harness (shared with fem_solver.stability) ---------------------------------

@dataclass(frozen=True)
class Case:
    """One run of a study: a scene, a setup and the overrides that make it this case."""
    name: str
    scene: str
    setup: str | None
    overrides: tuple[str, ...]
    description: str
    meta: dict = field(default_factory=dict, compare=False)   # copied into the case's row


def case_dir(out_dir: Path, name: str) -> Path:
    return Path(out_dir) / "cases" / name


def result_path(out_dir: Path, name: str) -> Path:
    return Path(out_dir) / "cases" / f"{name}.json"


def write_json_atomic(obj: dict, path: Path) -> None:
    """Write ``obj`` as JSON through a temporary file and a rename (a file that exists is whole)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=".json.tmp")
    try:
        with os.fdopen(fd, "w") as f:
            json.dump(obj, f, indent=1, default=_json_default)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"not JSON serialisable: {value!r}")


def load_result(out_dir: Path, case: Case) -> dict | None:
    """The stored result of ``case``, or None when absent, unreadable or made for other inputs."""
    path = result_path(out_dir, case.name)
    try:
        result = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    same = (result.get("scene") == case.scene and result.get("setup") == (case.setup or "")
            and result.get("overrides") == list(case.overrides))
    return result if same else None


def run_stats(cols: dict) -> dict:
    """Solver diagnostics of one run from its step columns (a dataset or partial records)."""
    n = len(cols["t"])
    if n == 0:
        return {"steps": 0}
    newton = np.asarray(cols["newton_iterations"])
    dt = np.asarray(cols["dt"])[1:]
    tip = np.asarray(cols["tip_uy"]) - cols["tip_uy"][0]
    return {
        "steps": n,
        "newton_iterations": int(newton.sum()),
        "max_newton_per_step": int(newton.max()),
        "cutbacks": int(np.sum(cols["cutbacks"])),
        "min_dt_s": float(dt.min()) if dt.size else math.nan,
        "max_dt_s": float(dt.max()) if dt.size else math.nan,
        "max_penetration_mm": float(np.max(cols["penetration_m"])) * 1e3,
        "max_force_residual_N": float(np.max(cols["force_balance_residual_N"])),
        "travel_mm": -float(np.min(cols["x"])) * 1e3 + 0.0,
        "solve_s": float(np.sum(cols["wall_time_s"])),
        "max_Fy_mN": float(np.max(cols["Fy"])) * 1e3,
        "max_tip_deflection_mm": float(np.max(np.abs(tip))) * 1e3,
        "last_t_s": float(cols["t"][-1]),
        "last_V": float(cols["V"][-1]),
        **instability_indicators(cols),
    }


def instability_indicators(cols: dict, from_fraction: float = 0.1) -> dict:
    """Signs of an approaching limit point (pull-in) in the accepted steps.

    ``tip_log_slope_max``: the largest d ln|Δtip| / d ln V between consecutive accepted
    steps with V ≥ ``from_fraction`` × the last voltage (Δtip: the free-end displacement
    since t = 0, as a vector): 2 for the small-strain V² law, larger as the actuator
    softens toward pull-in. ``dV_collapse``: the median accepted voltage increment over the
    last one — of order 1 for a smooth ramp, ≫ 1 when the cut-backs can no longer advance
    the voltage (the step size collapses at the limit point).
    """
    V = np.asarray(cols["V"], dtype=float)
    tip = np.stack([np.asarray(cols[k], dtype=float) for k in ("tip_ux", "tip_uy", "tip_uz")])
    d = np.linalg.norm(tip - tip[:, :1], axis=0)
    use = np.flatnonzero((V >= from_fraction * V[-1]) & (V > 0) & (d > 0))
    slope = math.nan
    if use.size >= 2:
        dv, dd = np.diff(np.log(V[use])), np.diff(np.log(d[use]))
        ok = dv > 0
        slope = float(np.max(dd[ok] / dv[ok])) if ok.any() else math.nan
    dV = np.diff(V)
    dV = dV[dV > 0]
    collapse = float(np.median(dV) / dV[-1]) if dV.size else math.nan
    return {"tip_log_slope_max": slope, "dV_collapse": collapse}


def _write_partial(records, scene, path: Path) -> None:
    """The accepted steps of a failed run, as a dataset marked incomplete (for diagnosis)."""
    from fem_solver import dataset
    ds = dataset.to_dataset(records, {"scene": scene.scene.name, "setup": scene.setup,
                                      "scene_toml": scene.to_toml()})
    ds.attrs["complete"] = 0
    dataset.write_atomic(ds, path)


def solve_case(case: Case, scene, out_dir: Path, comm, progress: bool) -> dict:
    """Solve one case; a failed or crashed solve becomes a result that says so."""
    import xarray as xr

    from fem_solver import dataset
    from fem_solver.run import solve_scene
    from fem_solver.stepping import SolveFailed, as_arrays
    run_dir = case_dir(out_dir, case.name)
    start = time.perf_counter()
    try:
        path = solve_scene(scene, run_dir, comm, progress=progress)
    except SolveFailed as err:
        wall = time.perf_counter() - start
        log.info("%s: %s", case.name, err)
        if err.records and comm.rank == 0:
            _write_partial(err.records, scene, run_dir / "partial.nc")
        stats = run_stats(as_arrays(err.records)) if err.records else {"steps": 0}
        return {"status": "failed", "reason": err.reason, "fail_t_s": err.t, "fail_V": err.voltage,
                "last_good_step": err.last_good_step, "wall_s": wall, **stats}
    except Exception as err:   # a crash of one case is that case's row, not the study's end
        log.exception("%s: crashed", case.name)
        return {"status": "error", "reason": f"{type(err).__name__}: {err}", "steps": 0,
                "wall_s": time.perf_counter() - start}
    wall = time.perf_counter() - start
    with xr.open_dataset(path, engine=dataset.ENGINE) as ds:
        cols = {name: ds[name].values for name in ds.data_vars}
        dofs = int(ds.attrs["mesh_dofs"])
    return {"status": "ok", "reason": "", "wall_s": wall, "dofs": dofs,
            "dataset": str(path.relative_to(out_dir)), **run_stats(cols)}


def _base_result(case: Case) -> dict:
    return {"case": case.name, "description": case.description, "scene": case.scene, "setup": case.setup or "",
            "overrides": list(case.overrides), **case.meta}


def resolve_cases(cases) -> tuple[dict, dict]:
    """Validate every case's scene before any work: ({name: Scene}, {name: rejection message})."""
    resolved, rejected = {}, {}
    for case in cases:
        try:
            resolved[case.name] = scenes.load(case.scene, setup=case.setup, overrides=case.overrides)
        except scenes.SceneError as err:
            rejected[case.name] = str(err)
    return resolved, rejected


def run_cases(cases, out_dir, comm, ranks_per_case: int = 1, desc: str = "cases") -> list[dict]:
    """Run a study's cases over rank groups; every rank returns the results in case order.

    ``mpirun -n N`` makes N / K groups of K ranks (``ranks_per_case``); group g solves the
    cases g, g + N/K, … of those without a stored result. A case whose scene fails
    validation is stored as ``rejected`` with the validation message, without solving.
    """
    out_dir = Path(out_dir)
    names = [c.name for c in cases]
    if len(set(names)) != len(names):
        raise InputError(f"case names must be unique: {names}")
    if ranks_per_case < 1 or comm.size % ranks_per_case:
        raise InputError(f"--ranks-per-case {ranks_per_case}: must divide the number of ranks ({comm.size})")
    resolved, rejected = resolve_cases(cases)
    if comm.rank == 0:
        for case in cases:
            if case.name in rejected and load_result(out_dir, case) is None:
                write_json_atomic({**_base_result(case), "status": "rejected", "reason": rejected[case.name],
                                   "steps": 0}, result_path(out_dir, case.name))
    todo = comm.bcast([c for c in cases if c.name in resolved and load_result(out_dir, c) is None]
                      if comm.rank == 0 else None, root=0)
    n_groups, color = comm.size // ranks_per_case, comm.rank // ranks_per_case
    initialise_petsc(comm)
    group = comm.Split(color, comm.rank)
    if comm.rank == 0:
        log.info("%s: %d cases, %d already done, %d to run on %d group(s) of %d rank(s) -> %s", desc, len(cases),
                 len(cases) - len(todo), len(todo), n_groups, ranks_per_case, out_dir)
    bar = tqdm(total=len(cases), initial=len(cases) - len(todo), desc=desc, unit="case", disable=comm.rank != 0)
    for case in todo[color::n_groups]:
        result = solve_case(case, resolved[case.name], out_dir, group, progress=comm.rank == 0)
        if group.rank == 0:
            write_json_atomic({**_base_result(case), **result}, result_path(out_dir, case.name))
        if comm.rank == 0:
            bar.n = sum(load_result(out_dir, c) is not None for c in cases)
            bar.refresh()
    idle_barrier(comm)
    bar.n = len(cases)
    bar.close()
    group.Free()
    return [load_result(out_dir, c) for c in cases]


def fmt(value, spec: str = ".3g") -> str:
    """A table cell: numbers formatted, NaN and None as '–'.

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
    return str(value).replace("|", "\\|")


def markdown_table(rows, columns) -> str:
    """``columns``: (header, key, format spec) triples."""
    lines = ["| " + " | ".join(h for h, _, _ in columns) + " |", "|" + "---|" * len(columns)]
    for row in rows:
        lines.append("| " + " | ".join(fmt(row.get(k), spec) for _, k, spec in columns) + " |")
    return "\n".join(lines)


def provenance() -> str:
    """One line: git commit and package versions (for the head of a study's Markdown)."""
    from fem_solver import dataset
    v = dataset.package_versions()
    return (f"git {dataset.git_commit()[:12]}, dolfinx {v['version_dolfinx']}, python {v['version_python']}, "
            f"numpy {v['version_numpy']}")


def write_text_atomic(text: str, path: Path) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


# --- the ladder ------------------------------------------------------------------------

@dataclass(frozen=True)
class Rung:
    """One discretisation, relative to the scene as loaded.

    ``resolution``: ``coarse`` (half the divisions in plane), ``base`` (as loaded), ``fine``
    (twice in plane), ``L1`` / ``L2`` (mesh.level + 1 / + 2: every direction × 2 / × 4).
    ``dt_factor`` scales the ladder's base ``time.dt_max_s``; ``shipped_dt`` uses the scene's
    own step instead (quick ladder only); ``poisson_ratio`` None keeps the scene's.
    """
    name: str
    cell: str
    order: int
    formulation: str
    resolution: str = "base"
    dt_factor: float = 1.0
    poisson_ratio: float | None = None
    shipped_dt: bool = False

    @property
    def elements(self) -> str:
        family = "Q" if self.cell == "hexahedron" else "P"
        u = f"{family}{self.order}"
        if self.formulation == "displacement":
            return f"{u} {self.cell[:3]}"
        return f"{u}–{family}{max(self.order - 1, 1)} {self.cell[:3]} mixed"


NU_DISPLACEMENT = 0.49        # pure displacement needs ν < 0.5
REFERENCE = "hex-Q2-mixed-L1-dthalf"
DEFAULT = "hex-Q2-mixed-L0"            # the shipped discretisation (the shipped step in a full ladder)
SHIPPED = "hex-Q2-mixed-L0-dtshipped"  # the same at the shipped step, in a quick ladder
HEX_Q2 = dict(cell="hexahedron", order=2)
TET_P2 = dict(cell="tetrahedron", order=2)
TET_P1 = dict(cell="tetrahedron", order=1)

LADDER = (
    Rung("hex-Q2-mixed-coarse", **HEX_Q2, formulation="mixed", resolution="coarse"),
    Rung(DEFAULT, **HEX_Q2, formulation="mixed"),
    Rung(SHIPPED, **HEX_Q2, formulation="mixed", shipped_dt=True),
    Rung("hex-Q2-mixed-L0-dt2x", **HEX_Q2, formulation="mixed", dt_factor=2.0),
    Rung("hex-Q2-mixed-L0-dthalf", **HEX_Q2, formulation="mixed", dt_factor=0.5),
    Rung("hex-Q2-mixed-fine", **HEX_Q2, formulation="mixed", resolution="fine"),
    Rung("hex-Q2-mixed-L1", **HEX_Q2, formulation="mixed", resolution="L1"),
    Rung(REFERENCE, **HEX_Q2, formulation="mixed", resolution="L1", dt_factor=0.5),
    Rung("hex-Q2-mixed-L0-nu049", **HEX_Q2, formulation="mixed", poisson_ratio=NU_DISPLACEMENT),
    Rung("hex-Q2-disp-L0-nu049", **HEX_Q2, formulation="displacement", poisson_ratio=NU_DISPLACEMENT),
    Rung("tet-P2-mixed-L0", **TET_P2, formulation="mixed"),
    Rung("tet-P2-disp-L0-nu049", **TET_P2, formulation="displacement", poisson_ratio=NU_DISPLACEMENT),
    Rung("tet-P1-disp-L0-nu049", **TET_P1, formulation="displacement", poisson_ratio=NU_DISPLACEMENT),
    Rung("tet-P1-disp-L1-nu049", **TET_P1, formulation="displacement", resolution="L1",
         poisson_ratio=NU_DISPLACEMENT),
    Rung("tet-P1-disp-L2-nu049", **TET_P1, formulation="displacement", resolution="L2",
         poisson_ratio=NU_DISPLACEMENT),
)
RUNG_SETS = ("quick", "full")
STUDY_STEPS = 100      # base steps of a quick study over the protocol


def protocol_overrides(base, protocol: str) -> tuple[str, ...]:
    """``quick``: the same protocol with a base step of end/100; ``full``: the scene's steps."""
    if protocol == "full":
        return ()
    dt = base.load.end_time_s / STUDY_STEPS
    return (f"time.dt_max_s={dt!r}", f"time.dt_initial_s={min(base.time.dt_initial_s, dt)!r}")


def _dt_overrides(dt: float, base) -> list[str]:
    return [f"time.dt_max_s={dt!r}", f"time.dt_initial_s={min(base.time.dt_initial_s, dt)!r}"]


def rung_overrides(rung: Rung, base, shipped) -> tuple[str, ...]:
    """The ``--set`` strings that turn the ladder's base scene into this rung (``shipped``: the
    scene as loaded, before the quick protocol)."""
    m = base.mesh
    out = [f"mesh.cell='{rung.cell}'", f"mesh.order={rung.order}", f"solver.formulation='{rung.formulation}'"]
    if rung.resolution == "coarse":
        out += [f"mesh.n_length={max(m.n_length // 2, 1)}", f"mesh.n_width={max(m.n_width // 2, 1)}"]
    elif rung.resolution == "fine":
        out += [f"mesh.n_length={2 * m.n_length}", f"mesh.n_width={2 * m.n_width}"]
    elif rung.resolution in ("L1", "L2"):
        out.append(f"mesh.level={m.level + int(rung.resolution[1])}")
    if rung.shipped_dt:
        out += [f"time.dt_max_s={shipped.time.dt_max_s!r}", f"time.dt_initial_s={shipped.time.dt_initial_s!r}"]
    elif rung.dt_factor != 1.0:
        out += _dt_overrides(base.time.dt_max_s * rung.dt_factor, base)
    if rung.poisson_ratio is not None:
        out.append(f"dea.poisson_ratio={rung.poisson_ratio!r}")
    return tuple(out)


def ladder_cases(scene_name: str, setup, rungs: str = "quick", overrides=(), only=None) -> list[Case]:
    """The ladder's cases; ``only`` picks rungs by name (the reference is always added)."""
    if rungs not in RUNG_SETS:
        raise InputError(f"--rungs {rungs!r}: expected one of {', '.join(RUNG_SETS)}")
    available = [r.name for r in LADDER if not (r.shipped_dt and rungs == "full")]
    chosen = list(only) if only else list(available)
    unknown = [n for n in chosen if n not in available]
    if unknown:
        raise InputError(f"--only {unknown[0]!r}: unknown rung for --rungs {rungs}; allowed: {', '.join(available)}")
    if REFERENCE not in chosen:
        chosen.append(REFERENCE)
    shipped = scenes.load(scene_name, setup=setup, overrides=overrides)
    protocol = protocol_overrides(shipped, rungs)
    base = scenes.load(scene_name, setup=setup, overrides=(*overrides, *protocol))
    default = SHIPPED if rungs == "quick" else DEFAULT
    cases = []
    for rung in LADDER:
        if rung.name not in chosen:
            continue
        sets = rung_overrides(rung, base, shipped)
        sc = scenes.load(scene_name, setup=setup, overrides=(*overrides, *protocol, *sets))
        meta = {"kind": "fem", "elements": rung.elements, "cell": rung.cell, "order": rung.order,
                "formulation": rung.formulation, "resolution": rung.resolution,
                "poisson_ratio": sc.dea.poisson_ratio, "dt_max_s": sc.time.dt_max_s, "protocol": rungs,
                "is_reference": rung.name == REFERENCE, "is_default": rung.name == default}
        cases.append(Case(rung.name, scene_name, base.setup or None, (*overrides, *protocol, *sets),
                          f"{rung.elements}, {rung.resolution} mesh, dt_max {sc.time.dt_max_s:.3g} s", meta))
    return cases


# --- errors against the reference ------------------------------------------------------

def trajectory_errors(ref: dict, run: dict) -> dict:
    """MAE of x(t) and Fy(t) on the reference's t, and the coin-travel error.

    ``ref``, ``run``: mappings with arrays ``t``, ``x``, ``Fy`` (an FEM dataset, or a
    surrogate's rollout on the same protocol). ``error_pct`` is the larger of the two MAEs
    as a percentage of the reference's travel and of its largest Fy.
    """
    t = np.asarray(ref["t"])
    x = np.interp(t, run["t"], run["x"])
    fy = np.interp(t, run["t"], run["Fy"])
    mae_x = float(np.mean(np.abs(x - ref["x"])))
    mae_fy = float(np.mean(np.abs(fy - ref["Fy"])))
    travel, travel_ref = -float(np.min(run["x"])) + 0.0, -float(np.min(ref["x"])) + 0.0
    fy_ref = float(np.max(np.abs(ref["Fy"])))
    rel_x = mae_x / travel_ref if travel_ref > 0 else math.nan
    rel_fy = mae_fy / fy_ref if fy_ref > 0 else math.nan
    rels = [r for r in (rel_x, rel_fy) if math.isfinite(r)]
    return {"mae_x_mm": mae_x * 1e3, "mae_Fy_mN": mae_fy * 1e3, "travel_err_mm": abs(travel - travel_ref) * 1e3,
            "travel_err_pct": 100 * abs(travel - travel_ref) / travel_ref if travel_ref > 0 else math.nan,
            "mae_x_pct": 100 * rel_x, "mae_Fy_pct": 100 * rel_fy,
            "error_pct": 100 * max(rels) if rels else math.nan}


def _columns(path: Path) -> dict:
    import xarray as xr

    from fem_solver import dataset
    with xr.open_dataset(path, engine=dataset.ENGINE) as ds:
        return {k: ds[k].values for k in ("t", "x", "Fy")}


TIME_KEY = "solve_s"   # time stepping incl. placement; meshing and the one-off form compilation excluded


def pareto_front(rows, error_key: str = "error_pct") -> set[str]:
    """Names of the FEM rows no faster FEM row (on :data:`TIME_KEY`) beats on ``error_key``
    (reference, failures and surrogate rows excluded: the front is the FEM's own)."""
    usable = [r for r in rows if r.get("status") == "ok" and not r.get("is_reference")
              and r.get("kind", "fem") == "fem"
              and math.isfinite(r.get(error_key, math.nan)) and r[error_key] > 0]
    front, best = set(), math.inf
    for r in sorted(usable, key=lambda r: (r[TIME_KEY], r[error_key])):
        if r[error_key] < best:
            front.add(r["case"])
            best = r[error_key]
    return front


def add_errors(rows, out_dir: Path) -> list[dict]:
    """Errors of every finished rung against the reference rung (NaN when it is missing)."""
    ref_row = next((r for r in rows if r.get("is_reference")), None)
    ref = _columns(Path(out_dir) / ref_row["dataset"]) if ref_row and ref_row["status"] == "ok" else None
    out = []
    for r in rows:
        r = dict(r)
        if ref is not None and r["status"] == "ok":
            r.update(trajectory_errors(ref, _columns(Path(out_dir) / r["dataset"])))
        out.append(r)
    for key, column in (("error_pct", "on_pareto"), ("travel_err_pct", "on_pareto_travel")):
        front = pareto_front(out, key)
        for r in out:
            r[column] = r["case"] in front
    nu = ref_row.get("poisson_ratio") if ref_row else None
    same = pareto_front([r for r in out if r.get("poisson_ratio") == nu])
    for r in out:
        r["on_pareto_same_nu"] = r["case"] in same
    return out


# --- outputs ---------------------------------------------------------------------------

CSV_COLUMNS = ("case", "kind", "status", "elements", "cell", "order", "formulation", "poisson_ratio",
               "resolution", "dt_max_s", "dofs", "steps", "newton_iterations", "cutbacks", "solve_s", "wall_s",
               "mae_x_mm", "mae_Fy_mN", "mae_x_pct", "mae_Fy_pct", "error_pct", "travel_mm", "travel_err_mm",
               "travel_err_pct", "is_reference", "is_default", "on_pareto", "on_pareto_travel", "on_pareto_same_nu", "reason",
               "protocol", "overrides")
MD_COLUMNS = (("rung", "case", ""), ("elements", "elements", ""), ("ν", "poisson_ratio", "g"),
              ("dt_max s", "dt_max_s", ".3g"), ("dofs", "dofs", "d"), ("steps", "steps", "d"),
              ("Newton its", "newton_iterations", "d"), ("solve s", "solve_s", "s"), ("wall s", "wall_s", "s"),
              ("MAE x mm", "mae_x_mm", ".3g"), ("MAE Fy mN", "mae_Fy_mN", ".3g"), ("travel mm", "travel_mm", ".3f"),
              ("travel err %", "travel_err_pct", ".2f"), ("error %", "error_pct", ".2f"),
              ("Pareto", "on_pareto", ""), ("Pareto, same ν", "on_pareto_same_nu", ""), ("status", "status", ""))


def write_csv(rows, path: Path) -> None:
    import pandas as pd
    df = pd.DataFrame([{c: (" ".join(r[c]) if c == "overrides" else r.get(c)) for c in CSV_COLUMNS} for r in rows])
    tmp = path.with_name(f".{path.name}.tmp")
    df.to_csv(tmp, index=False)
    os.replace(tmp, path)


def plot_pareto(rows, path: Path) -> None:
    """Log–log error against wall time, Pareto fronts joined, default and reference marked."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    panels = (("error_pct", "on_pareto", "error: max(MAE x / travel, MAE Fy / max Fy) [%]"),
              ("travel_err_pct", "on_pareto_travel", "coin-travel error [% of reference]"))
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.5))
    ref = next((r for r in rows if r.get("is_reference") and r["status"] == "ok"), None)
    for ax, (key, front_key, label) in zip(axes, panels):
        pts = [r for r in rows if r["status"] == "ok" and r.get(key, math.nan) > 0 and not r.get("is_reference")]
        for kind, marker in (("fem", "o"), ("surrogate", "s")):
            sel = [r for r in pts if r.get("kind", "fem") == kind]
            if sel:
                ax.scatter([r[TIME_KEY] for r in sel], [r[key] for r in sel], marker=marker,
                           color="C0" if kind == "fem" else "C2", label=f"{kind} rows", zorder=2)
        for r in pts:
            ax.annotate(r["case"], (r[TIME_KEY], r[key]), fontsize=7, xytext=(4, 3), textcoords="offset points")
        front = sorted((r for r in pts if r.get(front_key)), key=lambda r: r[TIME_KEY])
        if front:
            ax.step([r[TIME_KEY] for r in front], [r[key] for r in front], where="post", color="C1", lw=1.5,
                    label="Pareto front", zorder=1)
            ax.scatter([r[TIME_KEY] for r in front], [r[key] for r in front], s=90, facecolors="none",
                       edgecolors="C1", zorder=3)
        default = [r for r in pts if r.get("is_default")]
        if default:
            ax.scatter([default[0][TIME_KEY]], [default[0][key]], marker="*", s=300, color="C3", zorder=4,
                       label="shipped default")
        if ref is not None:
            ax.axvline(ref[TIME_KEY], color="grey", ls="--", lw=1, label=f"reference ({ref['case']})")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("run time: time stepping incl. placement, one core [s]")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
    # one legend under both panels: inside an axes it hid the points in its corner
    legend = {}
    for ax in axes:
        for handle, text in zip(*ax.get_legend_handles_labels()):
            legend.setdefault(text, handle)
    fig.legend(list(legend.values()), list(legend), loc="lower center", ncol=len(legend), fontsize=8,
               frameon=False)
    fig.suptitle("FEM fidelity ladder: error against run time (reference: finest affordable rung)")
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    tmp = path.with_name(f".{path.stem}.tmp{path.suffix}")
    fig.savefig(tmp, dpi=130)
    plt.close(fig)
    os.replace(tmp, path)


def default_verdict(rows) -> str:
    """Where the shipped default sits: its error, time and whether it is on the Pareto front."""
    d = next((r for r in rows if r.get("is_default")), None)
    if d is None or d["status"] != "ok" or not math.isfinite(d.get("error_pct", math.nan)):
        return "The shipped default rung did not run (or the reference is missing): no verdict."
    beaten = [r["case"] for r in rows if r["status"] == "ok" and not r.get("is_reference") and r is not d
              and r.get("kind", "fem") == "fem" and r[TIME_KEY] <= d[TIME_KEY]
              and r.get("error_pct", math.inf) < d["error_pct"]]
    where = "on the Pareto front" if d.get("on_pareto") else f"not on the Pareto front (beaten by {', '.join(beaten)})"
    where += (f"; among the rungs with the reference's ν = {d['poisson_ratio']:g} it is "
              f"{'on' if d.get('on_pareto_same_nu') else 'not on'} the front")
    return (f"Shipped default ({d['case']}, {d['elements']}): error {d['error_pct']:.2f} %, coin-travel error "
            f"{fmt(d.get('travel_err_pct'), '.2f')} %, solve {d[TIME_KEY]:.1f} s (wall {d['wall_s']:.1f} s), "
            f"{d['dofs']} dofs — {where}.")


def write_markdown(rows, path: Path, header: str) -> None:
    ref = next((r for r in rows if r.get("is_reference")), {})
    text = "\n".join([
        "# FEM fidelity ladder", "", header, "", f"Reference rung: `{ref.get('case', REFERENCE)}` "
        f"({fmt(ref.get('dofs'), 'd')} dofs, solve {fmt(ref.get(TIME_KEY), '.1f')} s, travel "
        f"{fmt(ref.get('travel_mm'), '.3f')} mm, status {ref.get('status', 'missing')}).", "",
        default_verdict(rows), "", markdown_table(rows, MD_COLUMNS), "",
        "error % = max(MAE x / reference travel, MAE Fy / reference max Fy); Pareto = no rung with a shorter "
        "solve time has a smaller error. solve s = time stepping incl. the initial placement; wall s adds "
        "meshing and the one-off form compilation (cached across runs). ν = 0.49 rungs include the change of "
        "material (rung hex-Q2-mixed-L0-nu049 isolates it). Surrogate rows (if any): a trained model rolled out "
        "over the sweep dataset of the same setup, solve s = the rollout; their error includes that of the FEM "
        "they learned from; the Pareto front is the FEM rungs'.", ""])
    write_text_atomic(text, path)


def report(rows, out_dir: Path, header: str = "") -> list[dict]:
    """Errors, CSV, Markdown and the Pareto plot of a finished ladder (rank 0)."""
    out_dir = Path(out_dir)
    rows = add_errors(rows, out_dir)
    write_csv(rows, out_dir / "fidelity.csv")
    write_markdown(rows, out_dir / "fidelity.md", header)
    plot_pareto(rows, out_dir / "fidelity_pareto.png")
    return rows


def run_ladder(scene_name: str, setup, out_dir, comm, rungs: str = "quick", overrides=(), only=None,
               ranks_per_case: int = 1, extra_rows=None) -> list[dict] | None:
    """Run (or resume) the ladder and write its report; rank 0 returns the rows, others None.

    ``extra_rows``: a callable run on rank 0 after the FEM rungs, returning more rows with
    a ``dataset`` of (t, x, Fy) to compare with the reference (the surrogates' rows,
    :func:`surrogate.ladder.ladder_rows`)."""
    out_dir = Path(out_dir)
    cases = ladder_cases(scene_name, setup, rungs, overrides, only)
    results = run_cases(cases, out_dir, comm, ranks_per_case, desc="fidelity")
    if comm.rank != 0:
        return None
    if extra_rows is not None:
        results = results + extra_rows(cases[0].setup)
    setup_name = cases[0].setup or "-"
    header = (f"Scene `{scene_name}`, setup `{setup_name}`, rungs `{rungs}`"
              f"{f' (base step end/{STUDY_STEPS}; the shipped step in rung {SHIPPED})' if rungs == 'quick' else ''}, "
              f"{comm.size} MPI rank(s), {ranks_per_case} per rung; extra --set: "
              f"{' '.join(overrides) or 'none'}. {provenance()}.")
    return report(results, out_dir, header)


def summary_table(rows) -> str:
    """Plain-text summary for the terminal."""
    lines = [f"{'rung':28s} {'dofs':>7s} {'solve s':>8s} {'error %':>8s} {'travel err %':>12s} pareto  status",
             "-" * 86]
    for r in rows:
        lines.append(f"{r['case']:28s} {fmt(r.get('dofs'), 'd'):>7s} {fmt(r.get(TIME_KEY), 's'):>8s} "
                     f"{fmt(r.get('error_pct'), '.2f'):>8s} {fmt(r.get('travel_err_pct'), '.2f'):>12s} "
                     f"{'*' if r.get('on_pareto') else ' ':>6s}  {r['status']}{' (reference)' if r.get('is_reference') else ''}")
    lines.append(default_verdict(rows))
    return "\n".join(lines)

