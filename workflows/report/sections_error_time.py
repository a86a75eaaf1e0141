"""The report's error-against-run-time section (the design card's ask): every FEM level, every
surrogate and the control loop on log–log axes, each point read from the result file that holds
it and offered as CSV beside the plot.

The points (:func:`error_time_points`):

* **FEM ladder** — ``fidelity.csv`` (``make fidelity``): every rung's wall time and its x(t) MAE
  and coin-travel error in % of the reference rung's travel (the reference rung itself: error 0
  by definition, not a point on a log axis);
* **FEM benchmark** — ``bench_fem.json`` (``make bench BENCH=fem``): the data fidelity and the preview
  on one core, their x(0.95 s) against the committed contact reference;
* **contact convergence** — ``bench/reference/contact_reference.json`` (``make fem-study``): each
  case of the contact ladders, its x(0.95 s) against the ladders' Richardson value; the bound of
  that value is drawn at the finest case's time (▼: the reference's error is at most that);
* **surrogates** — ``experiments.csv`` (``make experiments``): per model the mean over the sets of
  the 1 s rollout time and of the x(t) MAE in % of the travel; a model that diverged on any set
  has no finite error (drawn at the top edge, marked "diverged"); and the surrogate rows of the
  fidelity ladder when it has any;
* **the paper's ABAQUS** — 1 s in ``deapull.paper.ABAQUS_S``, its error not reported: a vertical line.

The control loop's error is another quantity (|x − x^T| at the end of an episode, in % of the
move), so it is a second panel (:func:`control_points`): per policy, plant and noise the median
episode wall time against the median final error, with the MPC's plan time per step in the CSV.

An input that is absent is a "not run" row with the make target that makes it, in the CSV and
on the figure; nothing is dropped silently.
"""
from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from deapull.paper import ABAQUS_S
from deapull.workflows.report.document import Report, Section, Table
from deapull.workflows.fidelity import ranks_suffix
from deapull.workflows.report.plots import BOUND, TRAVEL, X_MAE, plot_error_time
from deapull.workflows.report.sections_surrogates import MODEL_LABELS
from deapull.workflows.report.tabular import csv_text, fmt, num, read_csv, run_config

POINT_COLUMNS = ("group", "label", "metric", "wall_s", "error_pct", "status", "make", "source")
CONTROL_COLUMNS = ("policy", "plant", "noise_std_m", "episodes", "reached", "episode_wall_s_median",
                   "ms_per_iteration_median", "plan_ms_per_iteration_median", "final_error_pct_median",
                   "move_mm", "status", "make", "source")


def _true(value) -> bool:
    return str(value) in ("True", "true", "1")


def _point(group, label, metric, wall_s, error_pct, status, make, source) -> dict:
    return dict(group=group, label=label, metric=metric, wall_s=wall_s, error_pct=error_pct, status=status,
                make=make, source=str(source))


def _not_run(group: str, make: str, path: Path) -> dict:
    return _point(group, "–", "", None, None, "not run", make, path)


def fidelity_points(path: Path) -> list[dict]:
    """The ladder's rungs (FEM and the surrogates on it): x(t) MAE and travel error, % of travel."""
    out = []
    for r in read_csv(path):
        group = "FEM ladder" if r.get("kind", "fem") in ("", "fem") else "surrogate on the ladder"
        label, wall = r.get("case", "") + ranks_suffix(num(r, "ranks")), num(r, "wall_s")
        if r.get("status", "ok") != "ok":
            reason = r.get("reason", "")
            out.append(_point(group, label, "", wall, None, f"failed: {reason}" if reason else "failed", "", path))
            continue
        if _true(r.get("is_reference")):
            out.append(_point(group, label, "", wall, 0.0, "reference (the errors are against it)", "", path))
            continue
        for metric, key in ((X_MAE, "mae_x_pct"), (TRAVEL, "travel_err_pct")):
            e = num(r, key)
            if e is not None:
                out.append(_point(group, label, metric, wall, e, "ok", "", path))
    return out


def bench_points(path: Path) -> list[dict]:
    """``bench_fem.json``: each timed run's x(0.95 s) against the committed contact reference."""
    res = json.loads(path.read_text())
    out = []
    for label, r in res["runs"].items():
        if r.get("error_percent") is not None:
            out.append(_point("FEM benchmark", label, TRAVEL, r.get("wall_s"), abs(r["error_percent"]), "ok", "", path))
    return out


def reference_points(path: Path) -> list[dict]:
    """The contact study's cases: x(0.95 s) against the ladders' Richardson value; the bound at the
    wall time of the costliest case."""
    ref = json.loads(path.read_text())
    x_ref, out = ref.get("reference_x_at_t_mm"), []
    for case, c in ref.get("cases", {}).items():
        if x_ref and c.get("wall_s"):
            out.append(_point("contact convergence", case, TRAVEL, c["wall_s"], 100 * abs(c["x_at_t_mm"] / x_ref - 1),
                              "ok", "", path))
    walls = [c["wall_s"] for c in ref.get("cases", {}).values() if c.get("wall_s")]
    if walls and ref.get("bound_percent") is not None:
        out.append(_point("contact convergence", "reference", BOUND, max(walls), ref["bound_percent"],
                          "reference (its error is at most this bound)", "", path))
    return out


def surrogate_points(path: Path) -> list[dict]:
    """Per model: mean over the sets of the 1 s rollout time and of the x error in % of travel. A
    model that diverged on any set gets no error (status says on how many)."""
    rows = read_csv(path)
    out = []
    for kind in dict.fromkeys(r["model"] for r in rows):
        mine = [r for r in rows if r["model"] == kind]
        times = [v for v in (num(r, "rollout_ms") for r in mine) if v is not None]
        wall = float(np.mean(times)) / 1e3 if times else None
        n_div = sum(_true(r.get("diverged")) for r in mine)
        label = MODEL_LABELS.get(kind, kind)
        if n_div:
            out.append(_point("surrogate", label, X_MAE, wall, None, f"diverged on {n_div}/{len(mine)} sets",
                              "", path))
            continue
        errs = [num(r, "x_error_pct_travel") for r in mine]
        if not errs or any(e is None for e in errs):
            out.append(_point("surrogate", label, X_MAE, wall, None, "no error recorded", "", path))
            continue
        out.append(_point("surrogate", label, X_MAE, wall, float(np.mean(errs)), f"ok (mean of {len(mine)} sets)",
                          "", path))
    return out


def error_time_points(inputs) -> list[dict]:
    """Every point of the plot, read from the result files in ``inputs``; an absent file is one
    "not run" row naming its make target."""
    points = []
    for group, path, read, make in (
            ("FEM ladder", inputs.fidelity / "fidelity.csv", fidelity_points, "make fidelity"),
            ("FEM benchmark", inputs.bench_fem / "bench_fem.json", bench_points, "make bench BENCH=fem"),
            ("contact convergence", inputs.reference, reference_points, "make fem-study"),
            ("surrogate", inputs.experiments / "experiments.csv", surrogate_points, "make experiments")):
        points += read(path) if Path(path).is_file() else [_not_run(group, make, path)]
    points.append(_point("paper", "ABAQUS (Lahariya et al.)", "", ABAQUS_S, None, "error not reported: a line",
                         "", "deapull/paper.py"))
    return points


def _move_m(row: dict, default_m: float) -> float:
    """The distance the episode asks the coin to move: the last set point, else the run's target."""
    found = re.findall(r"-?[0-9.]+(?:e-?[0-9]+)?", str(row.get("setpoints_mm", "")))
    return abs(float(found[-1])) * 1e-3 if found else abs(default_m)


def control_points(folder: Path, make: str) -> list[dict]:
    """Per policy, plant and noise: median episode wall time and final |x − x^T| in % of the move."""
    path = folder / "control.csv"
    if not path.is_file():
        return [dict(policy="–", plant="–", status="not run", make=make, source=str(path))]
    target = run_config(folder).get("target_m") or -1e-3
    rows = [r for r in read_csv(path) if not r.get("status", "").startswith("unreachable")]   # no episode ran
    groups: dict = {}
    for r in rows:
        groups.setdefault((r["policy"], r["plant"], num(r, "noise_std_m")), []).append(r)
    out = []
    for (policy, plant, noise), sel in groups.items():
        def median(key, scale=1.0):
            vals = [num(r, key) for r in sel]
            vals = [v * scale for v in vals if v is not None]
            return float(np.median(vals)) if vals else None
        errs = [num(r, "final_abs_error_m") for r in sel]
        pcts = [100 * e / _move_m(r, target) for e, r in zip(errs, sel) if e is not None]
        out.append(dict(policy=policy, plant=plant, noise_std_m=noise, episodes=len(sel),
                        reached=sum(_true(r.get("reached")) for r in sel), episode_wall_s_median=median("episode_wall_s"),
                        ms_per_iteration_median=median("ms_per_iteration"),
                        plan_ms_per_iteration_median=median("solve_ms_per_iteration"),
                        final_error_pct_median=float(np.median(pcts)) if pcts else None,
                        move_mm=1e3 * _move_m(sel[0], target), status="ok", make="", source=str(path)))
    return out


def section_error_time(rep: Report) -> Section:
    sec = Section("error-time", "Error against run time: the FEM, the surrogates and control on one plot")
    inputs = rep.inputs
    points = error_time_points(inputs)
    ctrl = control_points(inputs.control, "make control") + control_points(inputs.control_fem, "make control PRESET=fem")
    for src in sorted({p["source"] for p in points + ctrl if p["status"] != "not run" and p["source"].endswith(
            (".csv", ".json"))}):                # sorted: a set's order changes with the hash seed
        rep.source(Path(src), sec)
    sec.p("Left: the wall time of one 1 s simulation of coin_pull C3 (log) against its error in % of the coin's "
          "travel (log): ● the x(t) MAE, ○ the coin-travel error, each against that study's reference (the fidelity "
          "ladder's finest rung; for the benchmark and the contact study's cases, x(0.95 s) against the "
          "committed reference, `bench/reference/contact_reference.json`, whose own bound is the ▼). "
          "Surrogates: the mean over the "
          "six sets of the 1 s rollout time and of the x(t) MAE on the test setup; a model that diverged on any set "
          "has **no** error, it sits on the top edge marked *diverged*. The paper's ABAQUS run (1 s in "
          f"{ABAQUS_S:g} s) is a vertical line: its error is not reported. Wall times were measured on shared "
          "machines (other jobs running), one core unless the study says otherwise: they rank, they do not "
          "benchmark.")
    sec.p("Right: control is another quantity — the coin's final |x − x^T| in % of the move it was asked for, "
          "against the wall time of a whole episode (median over the episodes of each policy, plant and noise); "
          "the MPC's plan time per step is in the CSV. It is drawn beside, not on the same axes.")
    name = "error_time.png"
    plot_error_time(points, ctrl, rep.img / name)
    sec.img(f"img/{name}", "Error against run time: FEM levels, surrogates, the ABAQUS line (left); closed-loop "
            "episodes (right). Grey text on the figure: inputs not run and their make targets.")
    sec.data("points", csv_text(points, POINT_COLUMNS), "CSV of the left panel's points (one row per point and "
             "metric; not-run inputs with their make target)")
    sec.data("control", csv_text(ctrl, CONTROL_COLUMNS), "CSV of the right panel's points (control)")
    rows = []
    for p in points:
        err = ("no finite error" if p["status"].startswith("diverged") else
               fmt(p["error_pct"], ".3g") if p["error_pct"] is not None else "–")
        rows.append([p["group"], p["label"], p["metric"] or "–", fmt(p["wall_s"], ".3g"), err, p["status"],
                     f"`{p['make']}`" if p["make"] else "–"])
    sec.table(Table(["group", "run", "metric", "wall s (1 s simulated)", "error % of travel", "status", "made by"],
                    rows, caption="The left panel's points"))
    not_run = [p for p in points + ctrl if p["status"] == "not run"]
    if not_run:
        sec.p("Not run (shown as such on the figure, no point): " + "; ".join(
            f"`{p['source']}` — `{p['make']}`" for p in not_run) + ".")
    return sec
