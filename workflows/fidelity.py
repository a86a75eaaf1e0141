"""Error against run time of the FEM: the fidelity ladder (``deapull fidelity``).

A *rung* is one FEM run of the same scene and setup with one discretisation: element
(P1 / P2 tetrahedra, Q2 hexahedra), formulation (mixed u–p or pure displacement),
resolution (coarse, the scene's mesh, finer in-plane, one or two uniform refinements)
and largest time step. The rungs are data, ``studies/fidelity.toml``
(:mod:`deapull.workflows.study_file`), each relative to the scene as loaded, so a tiny base mesh
gives a tiny ladder. Every rung is compared with the study's *reference rung* (the finest
affordable run: Q2–Q1 hexahedra refined once, half the time step): MAE of the coin position x(t)
and of the pressing force Fy(t), both interpolated onto the reference's t, and the error in coin
travel. Pure displacement needs ν < 0.5, so those rungs use ν = 0.49; their error includes that
modelling change (rung ``hex-Q2-mixed-L0-nu049`` measures it alone).

``rungs = "full"`` keeps the scene's protocol and steps (coin_pull: 1 s, dt_max 1/720 s, ≥ 720
points). ``"quick"`` keeps the 1 s protocol but makes the ladder's base step end/100 (0.01 s, ~100
points; the flow is quasi-static, so this moves the coin travel by ~0.2 %) and adds the rung with
``steps = "scene"`` (the scene's discretisation at the scene's step), so the default is still
placed on the ladder.

The rungs run on the study runner (:mod:`deapull.workflows.runner`): over MPI rank groups,
one atomic result JSON per rung, resumable.
"""
from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np

from deapull import dataset, provenance, scene as scenes
from deapull.errors import InputError
from deapull.io import atomic_write, cell as fmt, markdown_table, write_csv, write_json, write_text
from deapull.workflows import study_file
from deapull.workflows.runner import Case, run_cases

log = logging.getLogger(__name__)

PROTOCOLS = ("quick", "full")
STUDY_STEPS = 100      # base steps of a quick study over the protocol
#: the keys of a rung besides ``set`` and ``description``: its resolution's label, and ``steps =
#: "scene"`` for the rung at the scene's own steps (a quick ladder only)
RUNG_KEYS = {"resolution": None, "steps": ("scene",)}


def protocol_overrides(base, protocol: str) -> tuple[str, ...]:
    """``quick``: the same protocol with a base step of end/100; ``full``: the scene's steps."""
    if protocol == "full":
        return ()
    dt = base.load.end_time_s / STUDY_STEPS
    return (f"time.dt_max_s={dt!r}", f"time.dt_initial_s={min(base.time.dt_initial_s, dt)!r}")


def elements(scene) -> str:
    """The discretisation of a scene in words: ``Q2–Q1 hex mixed``, ``P1 tet``."""
    cell, order = scene.mesh.cell, scene.mesh.order
    family = "Q" if cell == "hexahedron" else "P"
    if scene.solver.formulation == "displacement":
        return f"{family}{order} {cell[:3]}"
    return f"{family}{order}–{family}{max(order - 1, 1)} {cell[:3]} mixed"


def ladder(study: str | Path = "fidelity") -> tuple[dict, dict]:
    """``[study]`` and the rungs of a ladder file; its reference and defaults name rungs."""
    head, entries = study_file.load(study, RUNG_KEYS)
    for key in ("reference", "default", "quick_default"):
        if head.get(key) not in entries:
            raise InputError(f"{head['path']}: study.{key} = {head.get(key)!r}: expected one of its rungs "
                             f"({', '.join(entries)})")
    return head, entries


def ladder_cases(scene_name: str, setup, rungs: str = "quick", overrides=(), only=None,
                 fidelity: str | None = None, study: str | Path = "fidelity") -> list[Case]:
    """The ladder's cases; ``only`` picks rungs by name (the reference is always added).
    ``fidelity`` names one of the scene's fidelities, applied to every rung before ``overrides``:
    each rung then refines or coarsens that fidelity's mesh and steps."""
    overrides = (*scenes.fidelity_overrides(scene_name, fidelity), *overrides)
    if rungs not in PROTOCOLS:
        raise InputError(f"--rungs {rungs!r}: expected one of {', '.join(PROTOCOLS)}")
    head, entries = ladder(study)
    available = {n: e for n, e in entries.items() if not (e.keys.get("steps") and rungs == "full")}
    chosen = study_file.pick(available, only, f"--only (rungs of --rungs {rungs})")
    if head["reference"] not in [e.name for e in chosen]:
        chosen.append(entries[head["reference"]])
    shipped = scenes.load(scene_name, setup=setup, overrides=overrides)
    protocol = protocol_overrides(shipped, rungs)
    base = scenes.load(scene_name, setup=setup, overrides=(*overrides, *protocol))
    common = study_file.resolve(head["set"], base, "study.set")
    default = head["quick_default"] if rungs == "quick" else head["default"]
    cases = []
    for rung in (e for e in available.values() if e in chosen):
        steps = () if rung.keys.get("steps") else protocol
        sets = (*common, *study_file.resolve(rung.set, base, f"cases.{rung.name}"))
        sc = scenes.load(scene_name, setup=setup, overrides=(*overrides, *steps, *sets))
        resolution = rung.keys.get("resolution", "base")
        meta = {"kind": "fem", "elements": elements(sc), "cell": sc.mesh.cell, "order": sc.mesh.order,
                "formulation": sc.solver.formulation, "resolution": resolution,
                "poisson_ratio": sc.dea.poisson_ratio, "dt_max_s": sc.time.dt_max_s, "protocol": rungs,
                "is_reference": rung.name == head["reference"], "is_default": rung.name == default}
        cases.append(Case(rung.name, scene_name, base.setup or None, (*overrides, *steps, *sets),
                          f"{meta['elements']}, {resolution} mesh, dt_max {sc.time.dt_max_s:.3g} s", meta))
    return cases


# --- errors against the reference ------------------------------------------------------

def _travel(x) -> float:
    """The coin's largest |x| (it starts at x = 0; either direction)."""
    return float(np.max(np.abs(np.asarray(x, dtype=float))))


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
    travel, travel_ref = _travel(run["x"]), _travel(ref["x"])
    fy_ref = float(np.max(np.abs(ref["Fy"])))
    rel_x = mae_x / travel_ref if travel_ref > 0 else math.nan
    rel_fy = mae_fy / fy_ref if fy_ref > 0 else math.nan
    rels = [r for r in (rel_x, rel_fy) if math.isfinite(r)]
    return {"mae_x_mm": mae_x * 1e3, "mae_Fy_mN": mae_fy * 1e3, "travel_err_mm": abs(travel - travel_ref) * 1e3,
            "travel_err_pct": 100 * abs(travel - travel_ref) / travel_ref if travel_ref > 0 else math.nan,
            "mae_x_pct": 100 * rel_x, "mae_Fy_pct": 100 * rel_fy,
            "error_pct": 100 * max(rels) if rels else math.nan}


def _ranks(path: Path) -> int | None:
    """The MPI ranks a rung's dataset was solved on (``mpi_ranks``; a result stored before the
    runner recorded ``ranks`` has it only there)."""
    ranks = dataset.read(path, variables=("t",)).attrs.get("mpi_ranks")
    return None if ranks is None else int(ranks)


def _columns(path: Path) -> dict:
    """t, x and Fy of a rung's dataset, or of a surrogate's rollout file in the same contract
    (a black box predicts no Fy: NaN then, and its error is the x part)."""
    cols = dict(dataset.read(path, variables=("t", "x"), optional=("Fy",)).columns)
    cols.setdefault("Fy", np.full_like(cols["x"], np.nan))
    return cols


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
        if r["status"] == "ok" and r.get("kind", "fem") == "fem" and r.get("ranks") is None:
            r["ranks"] = _ranks(Path(out_dir) / r["dataset"])
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

AS_WRITTEN = "as written"   # the fidelity of a ladder run on the scene file itself (no --fidelity)

CSV_COLUMNS = ("case", "kind", "fidelity", "status", "elements", "cell", "order", "formulation", "poisson_ratio",
               "resolution", "dt_max_s", "dofs", "ranks", "steps", "newton_iterations", "cutbacks", "solve_s", "wall_s",
               "mae_x_mm", "mae_Fy_mN", "mae_x_pct", "mae_Fy_pct", "error_pct", "travel_mm", "travel_err_mm",
               "travel_err_pct", "is_reference", "is_default", "on_pareto", "on_pareto_travel", "on_pareto_same_nu", "reason",
               "protocol", "overrides")
MD_COLUMNS = (("rung", "case", ""), ("elements", "elements", ""), ("ν", "poisson_ratio", "g"),
              ("dt_max s", "dt_max_s", ".3g"), ("dofs", "dofs", "d"), ("ranks", "ranks", "d"), ("steps", "steps", "d"),
              ("Newton its", "newton_iterations", "d"), ("solve s", "solve_s", "s"), ("wall s", "wall_s", "s"),
              ("MAE x mm", "mae_x_mm", ".3g"), ("MAE Fy mN", "mae_Fy_mN", ".3g"), ("travel mm", "travel_mm", ".3f"),
              ("travel err %", "travel_err_pct", ".2f"), ("error %", "error_pct", ".2f"),
              ("Pareto", "on_pareto", ""), ("Pareto, same ν", "on_pareto_same_nu", ""), ("status", "status", ""))


def ranks_suffix(ranks) -> str:
    """" (N ranks)" for a rung solved on more than one rank (its time is then shorter), else ""."""
    return f" ({int(ranks)} ranks)" if ranks is not None and int(ranks) > 1 else ""


def _label(row) -> str:
    return row["case"] + ranks_suffix(row.get("ranks"))


def plot_pareto(rows, path: Path) -> None:
    """Log–log error against wall time, Pareto fronts joined, default and reference marked."""
    import matplotlib  # lazy: matplotlib loads only for the plot
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # lazy: as above
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
            ax.annotate(_label(r), (r[TIME_KEY], r[key]), fontsize=7, xytext=(4, 3), textcoords="offset points")
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
            ax.axvline(ref[TIME_KEY], color="grey", ls="--", lw=1, label=f"reference ({_label(ref)})")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("run time: time stepping incl. placement [s], one core unless the label gives ranks")
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
    atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=130, format=path.suffix[1:]))
    plt.close(fig)


def default_verdict(rows) -> str:
    """Where the shipped default sits: its error, time and whether it is on the Pareto front."""
    d = next((r for r in rows if r.get("is_default")), None)
    if d is None or d["status"] != "ok" or not math.isfinite(d.get("error_pct", math.nan)):
        return "The shipped default rung did not run (or the reference is missing): no verdict."
    beaten = [r["case"] for r in rows if r["status"] == "ok" and not r.get("is_reference") and r is not d
              and r.get("kind", "fem") == "fem" and r[TIME_KEY] <= d[TIME_KEY]
              and r.get("error_pct", math.inf) < d["error_pct"]]
    where = "on the Pareto front" if d.get("on_pareto") else f"not on the Pareto front (beaten by {', '.join(beaten)})"
    on_ranks = f" on {int(d['ranks'])} ranks" if d.get("ranks") is not None and int(d["ranks"]) > 1 else ""
    where += (f"; among the rungs with the reference's ν = {d['poisson_ratio']:g} it is "
              f"{'on' if d.get('on_pareto_same_nu') else 'not on'} the front")
    return (f"Shipped default ({d['case']}, {d['elements']}): error {d['error_pct']:.2f} %, coin-travel error "
            f"{fmt(d.get('travel_err_pct'), '.2f')} %, solve {d[TIME_KEY]:.1f} s{on_ranks} (wall {d['wall_s']:.1f} s), "
            f"{d['dofs']} dofs — {where}.")


def ranks_line(rows) -> str:
    """How many MPI ranks shared each FEM rung's mesh. Solve times on more ranks are shorter than
    one core would give, so rungs that differ are named (the reference often runs on more)."""
    counts = {}
    for r in rows:
        if r.get("status") == "ok" and r.get("kind", "fem") == "fem" and r.get("ranks") is not None:
            counts.setdefault(int(r["ranks"]), []).append(r["case"])
    if not counts:
        return "Ranks per rung: not recorded."
    usual = max(counts, key=lambda n: (len(counts[n]), -n))
    text = f"Ranks per rung: {usual}"
    others = [f"{', '.join(counts[n])} on {n}" for n in sorted(counts) if n != usual]
    if others:
        n_other = sum(len(counts[n]) for n in counts if n != usual)
        text += (f", except {'; '.join(others)}: the solve time{'s' if n_other > 1 else ''} of "
                 f"{'those rungs' if n_other > 1 else 'that rung'} {'are' if n_other > 1 else 'is'} not on the "
                 f"others' {'one-core' if usual == 1 else f'{usual}-rank'} scale")
    return text + "."


def notes(rows, header: str) -> list[str]:
    """What the ladder refined (its header), its reference rung, the ranks and the default's verdict."""
    ref = next((r for r in rows if r.get("is_reference")), {})
    return [header, f"Reference rung: `{ref.get('case', 'missing')}` "
            f"({fmt(ref.get('dofs'), 'd')} dofs, {fmt(ref.get('ranks'), 'd')} rank(s), solve {fmt(ref.get(TIME_KEY), '.1f')} s, "
            f"travel {fmt(ref.get('travel_mm'), '.3f')} mm, status {ref.get('status', 'missing')}).", ranks_line(rows),
            default_verdict(rows)]


def write_markdown(rows, path: Path, header: str) -> None:
    lines = notes(rows, header)
    text = "\n".join([
        "# FEM fidelity ladder", "", *(x for line in lines for x in (line, "")), markdown_table(rows, MD_COLUMNS), "",
        "error % = max(MAE x / reference travel, MAE Fy / reference max Fy); Pareto = no rung with a shorter "
        "solve time has a smaller error. solve s = time stepping incl. the initial placement; wall s adds "
        "meshing and the one-off form compilation (cached across runs). ν = 0.49 rungs include the change of "
        "material (rung hex-Q2-mixed-L0-nu049 isolates it). Surrogate rows (if any): a trained model rolled out "
        "over the sweep dataset of the same setup, solve s = the rollout; their error includes that of the FEM "
        "they learned from; the Pareto front is the FEM rungs'.", ""])
    write_text(path, text)


def report(rows, out_dir: Path, header: str = "") -> list[dict]:
    """Errors, CSV, Markdown and the Pareto plot of a finished ladder (rank 0)."""
    out_dir = Path(out_dir)
    rows = add_errors(rows, out_dir)
    write_csv(out_dir / "fidelity.csv", rows, CSV_COLUMNS)
    write_json(out_dir / "fidelity.json", {"schema": 1, "git_commit": provenance.git_commit(),
                                           "notes": notes(rows, header)}, indent=2)
    write_markdown(rows, out_dir / "fidelity.md", header)
    plot_pareto(rows, out_dir / "fidelity_pareto.png")
    return rows


def run_ladder(scene_name: str, setup, out_dir, comm, rungs: str = "quick", overrides=(), only=None,
               ranks_per_case: int = 1, extra_rows=None, fidelity: str | None = None,
               study: str | Path = "fidelity") -> list[dict] | None:
    """Run (or resume) the ladder and write its report; rank 0 returns the rows, others None.

    ``extra_rows``: a callable run on rank 0 after the FEM rungs, returning more rows with
    a ``dataset`` of (t, x, Fy) to compare with the reference (the surrogates' rows,
    :func:`deapull.workflows.ladder.ladder_rows`)."""
    out_dir = Path(out_dir)
    cases = ladder_cases(scene_name, setup, rungs, overrides, only, fidelity, study)
    results = run_cases(cases, out_dir, comm, ranks_per_case, desc="fidelity")
    if comm.rank != 0:
        return None
    if extra_rows is not None:
        results = results + extra_rows(cases[0].setup)
    # a stored rung is reused only for the same overrides, which begin with the fidelity's: so every
    # row, stored or new (and a surrogate compared with them), is at this call's fidelity
    results = [{**r, "fidelity": fidelity or AS_WRITTEN} for r in results]
    setup_name = cases[0].setup or "-"
    scene_steps = next((c.name for c in cases if c.meta["is_default"]), "-")
    header = (f"Study `{study}` on scene `{scene_name}`, fidelity `{fidelity or AS_WRITTEN}`, setup `{setup_name}`, "
              f"rungs `{rungs}`{f' (base step end/{STUDY_STEPS}; the scene step in rung {scene_steps})' if rungs == 'quick' else ''}, "
              f"{comm.size} MPI rank(s) in this call, {ranks_per_case} per rung; extra --set: "
              f"{' '.join(overrides) or 'none'}. {provenance.summary()}.")
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
    lines.append(ranks_line(rows))
    return "\n".join(lines)

