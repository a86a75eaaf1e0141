"""Mesh-convergence studies defined as data: a TOML file of cases and ladders, solved by the one
runner (:mod:`deapull.workflows.runner`), summarised as observed orders, Richardson values and a
stated error bound.

A study file (``studies/<name>.toml``) has

* ``[study]``: ``scene``, ``setup``, ``time_s`` (the time at which x(t) is compared),
  ``safety_factor`` (Roache's F_s of the grid-convergence index, 1.25 for three levels);
* ``[cases]``: each case a list of ``--set`` overrides on the scene file as written;
* ``[ladders.<name>]``: ``cases`` (three, coarse to fine) and ``ratio`` (the refinement ratio r); the
  ladders share one case, from which each refines its own direction;
* ``[checks]``: ``dt`` (a pair: the change from halving the step, added to the bound whole),
  ``default`` (the data fidelity's case, compared with the Richardson value) and ``pairs`` (name ->
  [case, case]: two-level changes reported beside the bound, e.g. the contact rule and the penalty).

For each ladder with values f₃ (coarse), f₂, f₁ (fine) of a quantity, the observed order is
p = ln((f₃ − f₂)/(f₂ − f₁)) / ln r (defined when both differences have the same sign: a monotone
ladder), the Richardson value f₁ + (f₁ − f₂)/(r^p − 1), and the fine level's grid-convergence index
GCI = F_s |f₁ − f₂| / |f₁| / (r^p − 1). The quantities are x at ``time_s`` and the mean absolute
difference of x(t) between consecutive levels (its order from the ratio of the two differences).
The bound is the sum of the ladders' GCI on x(``time_s``) and the step's change: the two ladders
refine independent directions from their shared case, and with errors that add the reference is
Σ R_ladder − (n − 1) x(shared case).

    deapull fem-study --study contact_reference --out out/fem_study [--publish bench/reference]
"""
from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import numpy as np

from deapull import dataset
from deapull.errors import InputError
from deapull.io import write_json
from deapull.workflows import study_file

log = logging.getLogger(__name__)

SCHEMA = 1
#: the common time grid of the x(t) differences (s): every record of a 1 s ramp lies on 1/720 s steps
GRID = np.linspace(0.0, 1.0, 1001)
#: the grid on which the published result keeps each case's x(t) (s), so that a later run of the
#: study can take a case from it without its dataset (``reuse``)
SERIES = np.linspace(0.0, 1.0, 201)


def load_study(name_or_path: str | Path) -> dict:
    """The study file, checked: every ladder and check names defined cases, each ladder three."""
    path, study = study_file.read(name_or_path)
    if "ladders" not in study:
        raise InputError(f"{path}: missing [ladders]")
    cases = study["cases"]
    for name, overrides in cases.items():
        study_file.check_overrides(path, f"cases.{name}", overrides)
    for name, ladder in study["ladders"].items():
        names = ladder.get("cases", [])
        if len(names) != 3 or not all(n in cases for n in names):
            raise InputError(f"{path}: ladders.{name}.cases = {names!r}: expected three of the cases "
                             f"({', '.join(cases)}), coarse to fine")
        if not ladder.get("ratio", 0) > 1:
            raise InputError(f"{path}: ladders.{name}.ratio = {ladder.get('ratio')!r}: expected a number > 1")
    checks = study.get("checks", {})
    named = [*checks.get("dt", []), checks.get("default", ""), checks.get("corner", ""),
             *(n for pair in checks.get("pairs", {}).values() for n in pair), *checks.get("candidates", [])]
    unknown = [n for n in named if n and n not in cases]
    if unknown:
        raise InputError(f"{path}: [checks] names {unknown[0]!r}, not a case; cases: {', '.join(cases)}")
    pairs = checks.get("pairs", {})
    stray = [n for n in checks.get("converged", []) if n not in pairs]
    if stray:
        raise InputError(f"{path}: [checks] converged names {stray[0]!r}, not a pair of [checks.pairs]; pairs: "
                         f"{', '.join(pairs) or 'none'}")
    study["path"] = str(path)
    return study


def cases_of(study: dict) -> list:
    """The runner's cases of a study (the scene file as written plus each case's overrides)."""
    from deapull.workflows.runner import Case
    s = study["study"]
    return [Case(name, s["scene"], s.get("setup"), tuple(overrides), s.get("description", ""))
            for name, overrides in study["cases"].items()]


# --- the numbers -----------------------------------------------------------------------------

#: Roache's safety factor and order for a ladder outside its asymptotic range (no usable observed order)
FALLBACK_SAFETY, FALLBACK_ORDER = 3.0, 1.0


def observed(coarse: float, middle: float, fine: float, ratio: float, safety: float = 1.25) -> dict:
    """Observed order, Richardson value and the fine level's GCI (%) of one quantity on a ladder.

    Where the ladder turns back (not monotone) there is no order; where it is monotone but its
    steps do not shrink (order ≤ 0) the order is reported and there is no Richardson value or GCI:
    the ladder is not in its asymptotic range. ``gci_fixed_order_percent`` is Roache's fallback for
    such a ladder: the fine step with the order fixed at 1 and a safety factor of 3."""
    d_cm, d_mf = middle - coarse, fine - middle
    out = {"values": [coarse, middle, fine], "monotone": bool(d_cm * d_mf > 0),
           "gci_fixed_order_percent": 100.0 * FALLBACK_SAFETY * abs(d_mf / fine) / (ratio ** FALLBACK_ORDER - 1.0)}
    if not out["monotone"] or d_mf == 0:
        return {**out, "observed_order": math.nan, "richardson": math.nan, "gci_percent": math.nan}
    p = math.log(d_cm / d_mf) / math.log(ratio)
    if p <= 0:
        return {**out, "observed_order": p, "richardson": math.nan, "gci_percent": math.nan}
    factor = ratio ** p - 1.0
    return {**out, "observed_order": p, "richardson": fine + d_mf / factor,
            "gci_percent": 100.0 * safety * abs(d_mf / fine) / factor}


def order_of_differences(e_coarse: float, e_fine: float, ratio: float) -> float:
    """The order of a ladder from two successive differences (e.g. the MAE of x(t) between levels)."""
    if not (e_coarse > 0 and e_fine > 0):
        return math.nan
    return math.log(e_coarse / e_fine) / math.log(ratio)


def case_metrics(path: Path, time_s: float) -> dict:
    """x(time_s), x(1 s), the travel, the peak overlap at the contact points and the fewest contact
    points of a step that touches, from one case's dataset."""
    run = dataset.read(path, ("t", "x", "n_contact", "penetration_qp_m", "stick"))
    c = run.columns
    t, x = np.asarray(c["t"]), np.asarray(c["x"])
    touching = np.asarray(c["n_contact"])
    sliding = touching[(np.asarray(c["stick"]) == 0) & (touching > 0)]
    return {"x_at_t_mm": float(np.interp(time_s, t, x)) * 1e3, "x_end_mm": float(x[-1]) * 1e3,
            "travel_mm": float(np.max(np.abs(x))) * 1e3,
            "peak_overlap_um": float(np.max(c["penetration_qp_m"])) * 1e6,
            "min_points": int(touching[touching > 0].min()) if (touching > 0).any() else 0,
            "min_points_sliding": int(sliding.min()) if sliding.size else 0,
            "t": t, "x": x}


def mae_mm(a: dict, b: dict) -> float:
    """Mean absolute difference of x(t) of two cases on the common grid (mm); NaN where one has no x(t)."""
    if "t" not in a or "t" not in b:
        return math.nan
    return float(np.mean(np.abs(np.interp(GRID, a["t"], a["x"]) - np.interp(GRID, b["t"], b["x"])))) * 1e3


def summarise(study: dict, metrics: dict) -> dict:
    """The study's results: per ladder its orders, Richardson values and GCI; the bound; the
    default's error against the Richardson value; the checks. ``metrics``: case -> case_metrics."""
    s, checks = study["study"], study.get("checks", {})
    safety = float(s.get("safety_factor", 1.25))
    ladders, richardson, finest = {}, [], []
    for name, lad in study["ladders"].items():
        names, r = lad["cases"], float(lad["ratio"])
        if not all(n in metrics for n in names):
            # an incomplete ladder: its solved levels and the changes between neighbours that are solved
            vals = [metrics[n]["x_at_t_mm"] if n in metrics else None for n in names]
            changes = [100.0 * (b / a - 1.0) if a is not None and b is not None else None
                       for a, b in zip(vals[:-1], vals[1:])]
            ladders[name] = {"label": lad.get("label", name), "cases": names, "ratio": r, "complete": False,
                             "x_at_t_mm": vals, "changes_percent": changes, "observed_order_x_at_t": math.nan,
                             "richardson_x_at_t_mm": math.nan, "gci_x_at_t_percent": math.nan,
                             "observed_order_mae_x": math.nan, "mae_x_mm": [math.nan, math.nan],
                             "peak_overlap_um": [metrics[n]["peak_overlap_um"] if n in metrics else None
                                                 for n in names],
                             "min_points": min((metrics[n]["min_points"] for n in names if n in metrics), default=0)}
            continue
        m = [metrics[n] for n in names]
        x = observed(*(c["x_at_t_mm"] for c in m), r, safety)
        end = observed(*(c["x_end_mm"] for c in m), r, safety)
        e_cm, e_mf = mae_mm(m[0], m[1]), mae_mm(m[1], m[2])
        ladders[name] = {
            "label": lad.get("label", name), "cases": names, "ratio": r, "complete": True,
            "changes_percent": [100.0 * (m[1]["x_at_t_mm"] / m[0]["x_at_t_mm"] - 1.0),
                                100.0 * (m[2]["x_at_t_mm"] / m[1]["x_at_t_mm"] - 1.0)],
            "observed_order_x_at_t": x["observed_order"], "x_at_t_mm": x["values"], "monotone": x["monotone"],
            "richardson_x_at_t_mm": x["richardson"], "gci_x_at_t_percent": x["gci_percent"],
            "gci_fixed_order_x_at_t_percent": x["gci_fixed_order_percent"],
            "mae_x_mm": [e_cm, e_mf], "observed_order_mae_x": order_of_differences(e_cm, e_mf, r),
            "x_end_mm": end["values"], "observed_order_x_end": end["observed_order"],
            "peak_overlap_um": [c["peak_overlap_um"] for c in m],
            "peak_overlap_change_percent": 100.0 * abs(m[2]["peak_overlap_um"] / m[1]["peak_overlap_um"] - 1.0),
            "min_points": min(c["min_points"] for c in m),
        }
        richardson.append(x["richardson"])
        finest.append(x["richardson"] if np.isfinite(x["richardson"]) else x["values"][-1])
    out = {"schema": SCHEMA, "study": s.get("name", Path(study["path"]).stem), "scene": s["scene"],
           "setup": s.get("setup"), "time_s": float(s["time_s"]), "safety_factor": safety, "ladders": ladders,
           "cases": {n: {**{k: v for k, v in m.items() if k not in ("t", "x")}, **_series(m)}
                     for n, m in metrics.items()},
           "overrides": study["cases"]}
    dt = checks.get("dt", [])
    dt_change = (100.0 * abs(metrics[dt[1]]["x_at_t_mm"] / metrics[dt[0]]["x_at_t_mm"] - 1.0)
                 if len(dt) == 2 and all(n in metrics for n in dt) else math.nan)
    out["dt_change_percent"] = dt_change
    out["pairs"] = {name: {"cases": pair, "change_percent": 100.0 * (metrics[pair[1]]["x_at_t_mm"]
                                                                      / metrics[pair[0]]["x_at_t_mm"] - 1.0)}
                    for name, pair in checks.get("pairs", {}).items() if all(n in metrics for n in pair)}
    # a direction converged at the data fidelity's level (no ladder): its change on doubling is its error
    converged = checks.get("converged", [])
    out["converged_change_percent"] = (sum(abs(out["pairs"][n]["change_percent"]) for n in converged)
                                       if all(n in out["pairs"] for n in converged) else math.nan)
    gcis = [lad["gci_x_at_t_percent"] for lad in ladders.values()]
    complete = all(lad["complete"] for lad in ladders.values()) and len(ladders) == len(study["ladders"])
    out["bound_percent"] = (sum(gcis) + dt_change + out["converged_change_percent"]) if complete and gcis \
        else math.nan
    # with Roache's fallback (order 1, safety factor 3) for a ladder outside its asymptotic range
    fallback = [lad["gci_x_at_t_percent"] if np.isfinite(lad["gci_x_at_t_percent"])
                else lad.get("gci_fixed_order_x_at_t_percent", math.nan) for lad in ladders.values()]
    out["bound_fallback_percent"] = (sum(fallback) + dt_change + out["converged_change_percent"]) \
        if complete and fallback else math.nan
    # the reference value: with errors that add, x* = Σ R_ladder - (n - 1) x(shared case)
    shared = _shared_case(study)
    def additive(values):
        ok = complete and shared in metrics and values and all(np.isfinite(values))
        return metrics[shared]["x_at_t_mm"] + sum(v - metrics[shared]["x_at_t_mm"] for v in values) if ok else math.nan

    out["reference_x_at_t_mm"] = additive(richardson)
    # without a Richardson value, a ladder's finest level stands in for it (no extrapolation along it)
    out["reference_fallback_x_at_t_mm"] = additive(finest)
    default = checks.get("default", "")
    if default in metrics and np.isfinite(out["reference_x_at_t_mm"]):
        out["default_case"] = default
        out["default_error_percent"] = 100.0 * (metrics[default]["x_at_t_mm"] / out["reference_x_at_t_mm"] - 1.0)
    if default in metrics and np.isfinite(out["reference_fallback_x_at_t_mm"]):
        out["default_case"] = default
        out["default_error_fallback_percent"] = 100.0 * (metrics[default]["x_at_t_mm"]
                                                         / out["reference_fallback_x_at_t_mm"] - 1.0)
    # meshes that could replace the data fidelity: each one's error against the reference, at its cost
    if np.isfinite(out["reference_x_at_t_mm"]):
        out["candidates"] = {n: {"error_percent": 100.0 * (metrics[n]["x_at_t_mm"] / out["reference_x_at_t_mm"] - 1.0),
                                 "dofs": metrics[n].get("dofs"), "wall_s": metrics[n].get("wall_s"),
                                 "overrides": study["cases"][n]}
                             for n in checks.get("candidates", []) if n in metrics}
    return out


def _series(m: dict) -> dict:
    """A case's x(t) on :data:`SERIES` (mm), for the published result; none where the case has none."""
    if "t" not in m:
        return {}
    return {"x_series_mm": [round(float(v) * 1e3, 7) for v in np.interp(SERIES, m["t"], m["x"])]}


def reused_metrics(previous: dict, study: dict, names) -> dict:
    """The metrics of the cases ``names`` from a previously published result of the same study, where
    it holds the case with the same overrides: case -> its metrics (x(t) from its stored series, where
    it has one), marked ``reused``. A case whose overrides changed, or whose resolved scene differs from
    the one it was solved on (its ``scene_digest``: a changed scene file), is not taken."""
    out = {}
    for name in names:
        old = previous.get("cases", {}).get(name)
        if old is None or previous.get("overrides", {}).get(name) != study["cases"][name]:
            continue
        if "scene_digest" in old and not _solved_on_this_scene(study, name, old["scene_digest"]):
            continue
        m = {k: v for k, v in old.items() if k != "x_series_mm"}
        if "x_series_mm" in old:
            m.update(t=SERIES, x=np.asarray(old["x_series_mm"]) * 1e-3)
        out[name] = {**m, "reused": True}
    return out


def _solved_on_this_scene(study: dict, name: str, digest: str) -> bool:
    """Whether case ``name`` of ``study`` resolves today to the scene whose digest is ``digest``."""
    from deapull.workflows.runner import resolve_cases, scene_digest
    resolved, _ = resolve_cases([c for c in cases_of(study) if c.name == name])
    return name in resolved and scene_digest(resolved[name]) == digest


def keep_published_mae(result: dict, previous: dict) -> None:
    """A ladder whose x(t) differences are missing (cases reused from a result that kept no series)
    takes them from the previous result where that ladder had the same cases and x(time_s) values."""
    for name, lad in result["ladders"].items():
        old = previous.get("ladders", {}).get(name, {})
        if (lad.get("complete") and not all(np.isfinite(lad["mae_x_mm"])) and old.get("cases") == lad["cases"]
                and old.get("x_at_t_mm") == lad["x_at_t_mm"]):
            lad["mae_x_mm"], lad["observed_order_mae_x"] = old["mae_x_mm"], old["observed_order_mae_x"]
            lad["mae_from_previous_result"] = True


def _shared_case(study: dict) -> str:
    """The corner of the additive model: ``[checks] corner``, else the one case every ladder passes
    through. With x(a, b) = x* + e_a + e_b, R_a = x* + e_b at ladder b's level of a's direction and
    R_b = x* + e_a at ladder a's level of b's, so x* = R_a + R_b − x at (b's level of a, a's level of b)."""
    corner = study.get("checks", {}).get("corner", "")
    if corner:
        return corner
    common = set.intersection(*(set(lad["cases"]) for lad in study["ladders"].values()))
    return common.pop() if len(common) == 1 else ""


def bound_from_rungs(result: dict) -> float:
    """The bound (%) recomputed from the rungs' stored x(time_s) values alone: Σ GCI + the step's change."""
    total = result.get("converged_change_percent", 0.0)
    if not all(lad.get("complete", True) for lad in result["ladders"].values()):
        return math.nan
    for lad in result["ladders"].values():
        total += observed(*lad["x_at_t_mm"], lad["ratio"], result["safety_factor"])["gci_percent"]
    return total + result["dt_change_percent"]


def report_lines(result: dict) -> list[str]:
    """The study as text: each ladder, its orders and GCI, the bound and the default's error."""
    t = result["time_s"]
    lines = [f"{result['study']}: {result['scene']} {result['setup']}, x({t:g} s)"]
    for name, lad in result["ladders"].items():
        xs = " / ".join("–" if v is None else f"{v:.4f}" for v in lad["x_at_t_mm"])
        if not lad.get("complete", True):
            ch = ", ".join("–" if c is None else f"{c:+.3f} %" for c in lad["changes_percent"])
            lines.append(f"  {name} ({lad['label']}): x = {xs} mm, incomplete; level to level {ch}")
            continue
        if not np.isfinite(lad["gci_x_at_t_percent"]):
            lines.append(f"  {name} ({lad['label']}): x = {xs} mm, order {lad['observed_order_x_at_t']:.2f}: not in "
                         f"its asymptotic range (no Richardson value); with the order fixed at 1 and a safety "
                         f"factor of 3, GCI {lad.get('gci_fixed_order_x_at_t_percent', math.nan):.3f} %")
            continue
        lines.append(f"  {name} ({lad['label']}): x = {xs} mm, order {lad['observed_order_x_at_t']:.2f} "
                     f"(MAE of x(t) {lad['mae_x_mm'][0] * 1e3:.2f} / {lad['mae_x_mm'][1] * 1e3:.2f} um, order "
                     f"{lad['observed_order_mae_x']:.2f}), Richardson {lad['richardson_x_at_t_mm']:.4f} mm, "
                     f"GCI {lad['gci_x_at_t_percent']:.3f} %; peak overlap "
                     + " / ".join(f"{v:.2f}" for v in lad["peak_overlap_um"])
                     + f" um; fewest contact points {lad['min_points']}")
    lines.append(f"  halving the step: {result['dt_change_percent']:.3f} %")
    if result.get("converged_change_percent"):
        lines.append(f"  the converged directions' change on doubling: {result['converged_change_percent']:.3f} %")
    lines.append(f"  bound (sum of the GCIs, the step's change and the converged directions'): "
                 f"{result['bound_percent']:.3f} % (goal <= 1 %)")
    if not np.isfinite(result["bound_percent"]) and np.isfinite(result.get("bound_fallback_percent", math.nan)):
        lines.append(f"  bound with Roache's fallback for the ladders outside their asymptotic range: "
                     f"{result['bound_fallback_percent']:.3f} %")
    lines.append(f"  reference x({t:g} s) = {result['reference_x_at_t_mm']:.4f} mm")
    if not np.isfinite(result["reference_x_at_t_mm"]) and "default_error_fallback_percent" in result:
        lines.append(f"  with the finest level of a ladder without a Richardson value in its place: "
                     f"{result['reference_fallback_x_at_t_mm']:.4f} mm; the data fidelity "
                     f"{result['default_error_fallback_percent']:+.3f} % against it (goal within 2 %)")
    if "default_error_percent" in result:
        lines.append(f"  the data fidelity ({result['default_case']}): {result['default_error_percent']:+.3f} % "
                     f"against it (goal within 2 %)")
    for name, pair in result["pairs"].items():
        lines.append(f"  {name} ({pair['cases'][0]} -> {pair['cases'][1]}): {pair['change_percent']:+.3f} %")
    for name, c in result.get("candidates", {}).items():
        cost = f", {c['dofs']:,} dofs, {c['wall_s']:.0f} s" if c.get("dofs") and c.get("wall_s") else ""
        lines.append(f"  candidate {name} ({' '.join(c['overrides'])}{cost}): {c['error_percent']:+.3f} % against "
                     f"the reference")
    return lines


def run_study(name_or_path, out: Path, comm, ranks_per_case: int = 1, publish: Path | None = None,
              only=None, reuse: Path | None = None) -> dict | None:
    """Solve a study's cases (resuming; ``only``: just these), then, on rank 0, summarise every case
    solved so far into ``<out>/<study>.json`` (and ``<publish>/<study>.json``) and return it; the
    cases not solved are listed under ``failed`` with why. ``reuse``: a previously published result
    of the study, from which the cases not solved in ``out`` are taken (same overrides only; listed
    under ``reused``)."""
    from deapull.workflows.runner import load_result, run_cases
    study = load_study(name_or_path)
    name = Path(study["path"]).stem
    cases = cases_of(study)
    unknown = [n for n in (only or []) if n not in study["cases"]]
    if unknown:
        raise InputError(f"--only {unknown[0]!r}: not a case of {name}; its cases: {', '.join(study['cases'])}")
    chosen = [c for c in cases if not only or c.name in only]
    run_cases(chosen, out, comm, ranks_per_case, desc=name)
    results = [load_result(out, c) or {"case": c.name, "status": "not run"} for c in cases]
    if comm.rank != 0:
        return None
    metrics = {}
    for r in results:
        if r and r.get("status") == "ok":
            metrics[r["case"]] = case_metrics(Path(out) / r["dataset"], float(study["study"]["time_s"]))
            metrics[r["case"]].update(dofs=r["dofs"], wall_s=r["wall_s"], ranks=r["ranks"],
                                      **({"scene_digest": r["scene_digest"]} if "scene_digest" in r else {}))
    failed = {r["case"]: r.get("reason", "") for r in results if r.get("status") not in ("ok", "not run")}
    previous = json.loads(Path(reuse).read_text()) if reuse is not None else {}
    metrics.update(reused_metrics(previous, study, [n for n in study["cases"] if n not in metrics]))
    result = summarise(study, metrics)
    keep_published_mae(result, previous)
    result["failed"] = failed
    result["reused"] = sorted(n for n, m in metrics.items() if m.get("reused"))
    result["not_run"] = [r["case"] for r in results if r.get("status") == "not run" and r["case"] not in metrics]
    command = f"deapull fem-study --study {name} --out {out}"
    result["commands"] = ([*previous.get("commands", []), f"{command} --only {','.join(only or [])} --reuse {reuse}"]
                          if reuse is not None else [command])
    write_json(Path(out) / f"{name}.json", result, indent=2)
    if publish is not None:
        write_json(Path(publish) / f"{name}.json", result, indent=2)
    return result


def load_result(path: Path) -> dict:
    return json.loads(Path(path).read_text())
