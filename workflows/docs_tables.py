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

import numpy as np

from deapull.io import atomic_write, markdown_of
from deapull.paper import ABAQUS_S, CONTROL

REPO = Path(__file__).resolve().parents[1]


def _f(value, fmt: str) -> str:
    return "–" if value is None or (isinstance(value, float) and not math.isfinite(value)) else format(value, fmt)


def _um(value_m) -> str:
    """A length in m shown in µm to 0.1 (– for None)."""
    return _f(None if value_m is None else 1e6 * value_m, ".1f")


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
        gci = _f(lad['gci_x_at_t_percent'], '.3f')
        if gci == "–" and "gci_fixed_order_x_at_t_percent" in lad:
            gci = f"– ({_f(lad['gci_fixed_order_x_at_t_percent'], '.3f')} with the order fixed at 1, safety factor 3)"
        lines.append(f"| {lad['label']} | {xs} | {_f(lad['observed_order_x_at_t'], '.2f')} | "
                     f"{_f(lad['observed_order_mae_x'], '.2f')} | {_f(lad['richardson_x_at_t_mm'], '.4f')} | {gci} |")
    lines += ["", f"* halving the step changes x({t:g} s) by {_f(result['dt_change_percent'], '.3f')} %;"]
    if result.get("converged_change_percent"):
        lines.append(f"* the converged direction (rim band) changes it by {_f(result['converged_change_percent'], '.3f')} % "
                     "on doubling;")
    lines.append(f"* the bound (the ladders' GCIs, the step's change and the converged direction's): "
                 f"**{_f(result['bound_percent'], '.3f')} %** (goal ≤ 1 %); the reference x({t:g} s) = "
                 f"{_f(result['reference_x_at_t_mm'], '.4f')} mm;")
    if not _finite(result["bound_percent"]) and _finite(result.get("bound_fallback_percent")):
        lines.append(f"* with Roache's fallback for a ladder outside its asymptotic range (order 1, safety factor "
                     f"3): **{_f(result['bound_fallback_percent'], '.3f')} %**;")
    if "default_error_percent" in result:
        lines.append(f"* the data fidelity (the scene file as written): **{result['default_error_percent']:+.3f} %** "
                     "against it (goal within 2 %);")
    elif "default_error_fallback_percent" in result:
        lines.append(f"* with that ladder's finest level in place of its Richardson value the reference is "
                     f"{_f(result['reference_fallback_x_at_t_mm'], '.4f')} mm, and the data fidelity (the scene "
                     f"file as written) **{result['default_error_fallback_percent']:+.3f} %** against it (goal within 2 %);")
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
            f"| coin travel, C3 at 400 V | {_f(default.get('travel_mm'), '.3f')} mm | ≈ 1 mm (Fig. 4) |",
            f"| mesh-convergence bound on x({t:g} s) (two ladders, the rim band, the step) | {_bound(result)} | – |",
            f"| data fidelity against the reference | {_error(result)} | – |",
            f"| fewest contact points carrying the coin (data fidelity) | {default.get('min_points', '–')} | – |"]
    return "\n".join(rows)


def _finite(value) -> bool:
    return isinstance(value, (int, float)) and math.isfinite(value)


def _bound(result: dict) -> str:
    """The bound, or where a ladder has no observed order, Roache's fallback, saying so."""
    if _finite(result["bound_percent"]):
        return f"{result['bound_percent']:.2f} %"
    if _finite(result.get("bound_fallback_percent")):
        return f"none (a ladder outside its asymptotic range); {result['bound_fallback_percent']:.2f} % with Roache's fallback"
    return "–"


def _error(result: dict) -> str:
    if "default_error_percent" in result:
        return f"{result['default_error_percent']:+.2f} % (Richardson)"
    if "default_error_fallback_percent" in result:
        return f"{result['default_error_fallback_percent']:+.2f} % (the tip ladder's finest level in place of its Richardson value)"
    return "–"


def _ms(pair, scale: float, fmt: str = ".3g") -> str:
    """"mean ± std" of a [mean, std] pair (– when None)."""
    if not pair or pair[0] is None:
        return "–"
    return format(pair[0] / scale, fmt) + (f" ± {pair[1] / scale:.2g}" if pair[1] else "")


def surrogate_table2(result: dict) -> str:
    """The paper's Table II beside ours (mean over the six test setups; mean ± std over the repeats),
    then x error per set with the ensemble band's coverage."""
    kinds, labels, paper = result["kinds"], result["labels"], result["paper"]
    rows = [f"| mean over the {len(result['sets'])} test setups ({result['repeats']} repeats) | "
            + " | ".join(labels[k] for k in kinds) + " | paper f | paper LSTM | paper NN |",
            "|---|" + "---|" * (len(kinds) + 3)]
    for key, label, scale in (("mae_x_m", "MAE x [1e-4 m]", 1e-4), ("mae_Fx_N", "MAE Fx [1e-4 N]", 1e-4),
                              ("mae_Fy_N", "MAE Fy [1e-4 N]", 1e-4), ("x_error_pct_travel", "x error [% of travel]", 1),
                              ("rollout_ms", "1 s rollout [ms]", 1)):
        cells = [_ms(result["table2"][k][key], scale) for k in kinds]
        ref = [paper.get(key, {}).get(m) for m in ("f", "lstm", "nn")]
        rows.append(f"| {label} | " + " | ".join(cells) + " | "
                    + " | ".join("–" if v is None else f"{v / scale:.3g}" for v in ref) + " |")
    rows.append("| diverged rollouts | " + " | ".join(str(result["diverged"][k]) for k in kinds) + " | | | |")
    banded = [k for k in kinds if k in result.get("band_coverage", {})]
    rows += ["", "| set (train/val/test) | " + " | ".join(f"{labels[k]} x error [%]" for k in kinds)
             + "".join(f" | {labels[k]} {round(100 * result['band_level'])} % band covers [%]" for k in banded) + " |",
             "|---|" + "---|" * (len(kinds) + len(banded))]
    for i, rec in result["per_set"].items():
        cells = [_ms(rec[k]["x_error_pct_travel"], 1, ".2f")
                 + (f" ({rec[k]['diverged']}/{result['repeats']} diverged)" if rec[k].get("diverged") else "")
                 for k in kinds]
        cells += [_ms(rec[k]["band_coverage"], 0.01, ".1f") for k in banded]
        rows.append(f"| {i} ({'/'.join(rec['train_val_test'])}) | " + " | ".join(cells) + " |")
    rows.append("")
    for k, n in result["ahead"].items():
        rows.append(f"* {labels[k]} ahead of the black boxes (MAE x) on **{n}/{len(result['sets'])}** sets;")
    for k, c in result.get("band_coverage", {}).items():
        rows.append(f"* its {round(100 * result['band_level'])} % band covers {100 * c['mean']:.1f} % of the test "
                    f"runs' points (lowest rollout {100 * c['min']:.1f} %; goal ≥ 80 %);")
    rows.append(f"* data: fidelity {', '.join(result['data']['fidelity'])} "
                f"({', '.join(result['data']['fidelity_id'])}).")
    return "\n".join(rows)


def surrogate_pairs(result: dict) -> str:
    """x error of each held-out run (% of travel), one friction pair left out at a time; the largest
    per kind on the ramps (goal ≤ 1 %) and on the excitation runs (goal ≤ 2 %) apart."""
    kinds, labels = result["kinds"], result["labels"]
    rows = ["| held-out pair | trained on (validated on) | run | travel mm | "
            + " | ".join(f"{labels[k]} [%]" for k in kinds) + " |", "|---|---|---|---|" + "---|" * len(kinds)]
    for r in result["runs"]:
        d = result["designs"][r["pair"]]
        rows.append(f"| {r['pair']} | {','.join(d['train'])} ({','.join(d['val'])}) | {r['run']} | "
                    f"{1e3 * r['travel_m']:.3f} | " + " | ".join(_f(r[k], ".2f") for k in kinds) + " |")
    rows.append("")
    for what, goal, group in (("ramps", 1, [r for r in result["runs"] if r.get("protocol", "ramp") == "ramp"]),
                              ("excitation runs", 2, [r for r in result["runs"] if r.get("protocol", "ramp") != "ramp"])):
        for k in kinds if group else ():
            worst = max((r[k] if r[k] is not None else math.inf) for r in group)
            shown = f"largest {_f(worst, '.2f')} %" if math.isfinite(worst) else "a rollout diverged"
            rows.append(f"* {labels[k]}, held-out {what}: {shown} (goal ≤ {goal} %);")
            cover = [r["band_coverage"][k] for r in group if k in r.get("band_coverage", {})]
            width = [r["band_half_width_pct_travel"][k] for r in group if k in r.get("band_half_width_pct_travel", {})]
            width = f", its mean half-width {sum(width) / len(width):.1f} % of travel" if width else ""
            if cover:
                rows.append(f"* {labels[k]}, held-out {what}: its {100 * result.get('band_level', 0.9):.0f} % band covers "
                            f"{100 * sum(cover) / len(cover):.1f} % of the points (lowest {100 * min(cover):.1f} %; "
                            f"goal ≥ 80 %){width};")
    if "data" in result:
        rows.append(f"* data: fidelity {', '.join(result['data']['fidelity'])} "
                    f"({', '.join(result['data']['fidelity_id'])});")
    rows[-1] = rows[-1].rstrip(";") + "."
    return "\n".join(rows)


def surrogate_headline(result: dict) -> str:
    """The README's surrogate line: the default model's pooled MAE of x beside the paper's."""
    k = "f-coulomb" if "f-coulomb" in result["kinds"] else result["kinds"][0]
    paper = result["paper"]["mae_x_m"]
    worst = max((rec[k]["x_error_pct_travel"] or [math.inf])[0] for rec in result["per_set"].values())
    return "\n".join([
        "| what | ours | paper |", "|---|---|---|",
        f"| surrogate: MAE of x over the six test setups (Table II) | {_ms(result['table2'][k]['mae_x_m'], 1e-4)} "
        f"× 1e-4 m | f {paper['f'] / 1e-4:.2f}, LSTM {paper['lstm'] / 1e-4:.2f}, NN {paper['nn'] / 1e-4:.2f} × 1e-4 m |",
        f"| surrogate: sets where f leads NN and LSTM; its worst set | {result['ahead'].get(k)}/{len(result['sets'])}; "
        f"{_f(worst, '.2f')} % of travel | – |"])


def control_goals(result: dict) -> str:
    """The control table (surrogate plants) and the MPC's goals G1–G4 measured against it."""
    groups = result["groups"]
    rows = ["| policy | plant | noise (m) | reached | settled | median iterations | settled within 100 | "
            "episodes 2–N settled (median) | largest overshoot µm |", "|---|---|---|---|---|---|---|---|---|"]
    for g in groups:
        rows.append(f"| {g['policy']} | {g['plant']} | {g['noise_std_m']:g} | {g['reached']}/{g['episodes']} | "
                    f"{g['settled']}/{g['episodes']} | {_f(g['median_iterations'], '.0f')} | "
                    f"{g['settled_within_100']} | {g['later_settled']}/{g['later_episodes']} "
                    f"({_f(g['later_median_iterations'], '.0f')}) | "
                    f"{_um(g['largest_overshoot_m'])} |")
    mpc = [g for g in groups if g["policy"] == "mpc"]

    def at(noise):
        return [g for g in mpc if math.isclose(g["noise_std_m"], noise, rel_tol=1e-9, abs_tol=1e-15)]

    def pooled(gs, key):
        return sum(g[key] for g in gs)
    lines = []
    for noise in (0.0, 1e-4, 1e-3):
        gs = at(noise)
        if gs:
            ok = all(g["reached"] == g["episodes"] and (g["median_iterations"] or math.inf) <= 100 for g in gs)
            lines.append(f"* G1 at noise {noise:g}: " + ", ".join(
                f"{g['plant']} reached {g['reached']}/{g['episodes']}, median {_f(g['median_iterations'], '.0f')}"
                for g in gs) + f" (goal 10/10, median ≤ 100: {'met' if ok else 'not met'});")
    gs = at(1e-4)
    if gs:
        n, settled, within = pooled(gs, "episodes"), pooled(gs, "settled"), pooled(gs, "settled_within_100")
        medians = [g["median_settled_iterations"] for g in gs]
        ok = settled == n and within >= 0.8 * n and all(m is not None and m <= 300 for m in medians)
        lines.append(f"* G2 at 1e-4: settled {settled}/{n}, medians " + ", ".join(_f(m, ".0f") for m in medians)
                     + f", within 100 iterations {within}/{n} (goal {n}/{n}, median ≤ 300, ≥ {round(0.8 * n)}/{n} "
                     f"within 100: {'met' if ok else 'not met'});")
        later, later_settled = pooled(gs, "later_episodes"), pooled(gs, "later_settled")
        later_medians = [g["later_median_iterations"] for g in gs]
        ok = later_settled == later and all(m is not None and m <= 100 for m in later_medians)
        lines.append(f"* G3 at 1e-4, episodes 2–N: settled {later_settled}/{later}, medians "
                     + ", ".join(_f(m, ".0f") for m in later_medians)
                     + f" (goal all, median ≤ 100: {'met' if ok else 'not met'});")
    gs = at(1e-3)
    if gs:
        lines.append(f"* G4 at 1e-3: settled {pooled(gs, 'settled')}/{pooled(gs, 'episodes')} (reported; reaching is G1).")
    if lines:
        lines[-1] = lines[-1].rstrip(";.") + "."
    return "\n".join(rows + [""] + lines)


def _commit(commit: str | None) -> str:
    """A git commit as its short hash; any other note (e.g. "before fd8c86c") as it is."""
    if not commit:
        return "unknown"
    return commit[:7] if re.fullmatch(r"[0-9a-f]{7,40}", commit) else commit


def control_fem(result: dict) -> str:
    """The MPC on the FEM plants (``make control PRESET=fem``): per plant its target and each
    episode's iterations, and goal G5 pooled over the plants."""
    groups = [g for g in result["groups"] if g["policy"] == "mpc"]
    # the commit that ran each plant (a group's own where plants were run one command each)
    commits = [g.get("git_commit", result.get("git_commit")) for g in groups]
    made = any(commits)
    rows = ["| plant | target (mm) | iterations to the target, by episode | settled | largest overshoot µm |"
            + (" run at commit |" if made else ""), "|---|---|---|---|---|" + ("---|" if made else "")]
    for g, commit in zip(groups, commits):
        its = " / ".join("–" if n is None else f"{n:.0f}" for n in g.get("iterations", []))
        rows.append(f"| {g['plant']} | {g['task']} | {its} | {g['settled']}/{g['episodes']} | "
                    f"{_um(g['largest_overshoot_m'])} |" + (f" {_commit(commit)} |" if made else ""))
    settled = sum(g["settled"] for g in groups)
    episodes = sum(g["episodes"] for g in groups)
    its = sorted(n for g in groups for n in g.get("iterations", []) if n is not None)
    median = float(np.median(its)) if its else None
    worst = max((g["largest_overshoot_m"] or 0.0) for g in groups) if groups else None
    plants = len(groups)
    ok = plants == 8 and settled >= 22 and (worst or 0.0) <= 1e-5 and median is not None and median <= 450
    line = (f"G5 on {plants} of the 8 FEM plants: settled {settled}/{episodes}, median {_f(median, '.0f')} iterations, "
            f"largest overshoot {_f(None if worst is None else 1e6 * worst, '.1f')} µm (goal on all 8: ≥ 22/24, "
            f"overshoot ≤ 10 µm, median ≤ 450, moonshot 300: {'met' if ok else 'not met'}).")
    return "\n".join(rows + ["", line])


def control_fem_multi(result: dict) -> str:
    """The multi-setpoint task on an FEM plant (``make control PRESET=fem``'s second command): per
    episode the iterations to each setpoint and how many settled."""
    rows = ["| plant | setpoints (mm) | episode | iterations to each setpoint | setpoints settled | largest overshoot µm |",
            "|---|---|---|---|---|---|"]
    every = total = 0
    for g in (g for g in result["groups"] if g["policy"] == "mpc"):
        n = len(g["task"].split(";"))
        for k, (its, settled) in enumerate(zip(g["iterations_per_setpoint"], g["setpoints_settled"])):
            rows.append(f"| {g['plant']} | {g['task'].replace(';', ', ')} | {k + 1} | "
                        f"{' / '.join('–' if i is None else str(i) for i in its)} | {settled}/{n} | "
                        f"{_um(g['largest_overshoot_m'])} |")
            every, total = every + (settled == n), total + 1
    line = (f"Every setpoint settled in {every} of {total} episode(s) (goal: settled at every setpoint, with G5's "
            f"setting: {'met' if total and every == total else 'not met'}).")
    return "\n".join(rows + ["", line])


def inference_calibration(result: dict) -> str:
    """What the online inference tells (G6): per loss, prior and set of true coins, the onset's and each
    field's error and how often the 68 % interval (and the Laplace one beside it) covers the truth."""
    rows = ["| loss | prior | true coins | interval | onset error, median / max [%] | μ_b error [%] | μ_t error [%] "
            "| m_c error [%] | 68 % interval covers μ_b / μ_t / m_c [%] | Laplace covers [%] |",
            "|---|---|---|---|---|---|---|---|---|---|"]
    fields = ("mu_b", "mu_t", "mass_kg")
    for r in result["runs"]:
        truths = {"design": "C1..C8", "family": "family draws"}.get(r.get("truths", "design"))
        cover = " / ".join(f"{100 * r[f]['coverage_68']:.0f}" for f in fields)
        laplace = " / ".join(f"{100 * r[f].get('coverage_68_laplace', r[f]['coverage_68']):.0f}" for f in fields)
        rows.append(f"| {r['loss']} | {r['prior']} | {truths} | {r.get('interval', 'laplace')} | "
                    f"{100 * r['onset_abs_error_median']:.2f} / {100 * r['onset_abs_error_max']:.2f} | "
                    f"{100 * r['mu_b']['abs_error_median']:.1f} | {100 * r['mu_t']['abs_error_median']:.1f} | "
                    f"{100 * r['mass_kg']['abs_error_median']:.2f} | {cover} | {laplace} |")
    rows += ["", f"{result['kind']} f_a as its own plant, {result['seeds']} seeds per row, noise "
             f"{result['noise_m']:g} m, {result['steps']} steps of the push (goal: μ_b and the onset within 10 %, "
             f"the 68 % interval covering 58–78 %)."]
    return "\n".join(rows)


def stability(result: dict) -> str:
    """``make stability``: the suite's table as its run wrote it (stability.json), its header, the
    pull-in detections and the cases that did not do what they were expected to."""
    table = result["table"]
    keep = ("case", "as expected", "steps", "Newton its", "cut-backs", "fewest contact pts", "travel mm", "wall s",
            "outcome")
    cols = [table["headers"].index(h) for h in keep if h in table["headers"]]
    lines = [markdown_of({"headers": [table["headers"][i] for i in cols],
                          "rows": [[row[i] for i in cols] for row in table["rows"]]})]
    unexpected = result["not_as_expected"]
    lines += ["", result["header"], ""] + [f"* {note}" for note in result["pull_in"]]
    lines += ["", f"{len(table['rows']) - len(unexpected)} of {len(table['rows'])} cases as expected"
              + (f"; not as expected: {', '.join(unexpected)}." if unexpected else ".")]
    return "\n".join(lines)


def fem_speed(result: dict) -> str:
    """``make bench BENCH=fem``: C3 on one core at the data fidelity beside the baseline timed in the same
    run, the preview, the sweep when timed, ABAQUS and the goals."""
    ref, goals = result.get("reference", {}), result["goals"]
    t = ref.get("time_s", 0.95)
    runs = result["runs"]
    base = next((v for k, v in runs.items() if k.startswith("baseline")), None)
    rows = [f"| run (coin_pull C3, one core) | wall s | vs baseline | vs ABAQUS | points | dofs | Newton its | "
            f"x({t:g} s) mm | vs reference |", "|---|---|---|---|---|---|---|---|---|"]
    for label, r in runs.items():
        speed = f"{base['wall_s'] / r['wall_s']:.2f}x" if base else "–"
        err = f"{r['error_percent']:+.2f} %" if r.get("error_percent") is not None else "–"
        rows.append(f"| {label} | {r['wall_s']:.0f} | {speed} | {ABAQUS_S / r['wall_s']:.2f}x | {r['points']} | "
                    f"{r['dofs']} | {r['newton_its']} | {r['x_at_t_mm']:.4f} | {err} |")
    rows.append(f"| ABAQUS (paper) | {ABAQUS_S:.0f} | – | 1.00x | – | – | – | – | – |")
    sweep = result.get("sweep")
    rows += ["", f"Goals: C3 ≤ {goals['c3_one_core_s']:.0f} s on one core (moonshot {goals['moonshot_s']:.0f} s); "
             f"the 8-setup sweep ≤ {goals['sweep_s']:.0f} s on 2 ranks: "
             + (f"{sweep['wall_s']:.0f} s on {sweep['np']} ranks." if sweep else "not timed in this run (`--skip-sweep`).")]
    return "\n".join(rows)


def fem_speed_headline(result: dict) -> str:
    """The README's row of the FEM's speed (``make bench BENCH=fem``)."""
    data = result["runs"].get("data fidelity (scene file)", {})
    base = next((v for k, v in result["runs"].items() if k.startswith("baseline")), {})
    return "\n".join(["| what | ours | paper |", "|---|---|---|",
                      f"| FEM of one 0→400 V ramp (coin_pull C3, data fidelity), one core | {_f(data.get('wall_s'), '.0f')} s "
                      f"at {data.get('dofs', '–')} dofs (the solver path before its last speed-up: "
                      f"{_f(base.get('wall_s'), '.0f')} s, same run) | {ABAQUS_S:.0f} s (ABAQUS) |"])


def control_headline(result: dict) -> str:
    """The README's control lines (``make control``): the MPC on the surrogate plants at each noise,
    reached and settled, beside the paper's criterion (Fig. 6)."""
    rows = ["| what | ours | paper |", "|---|---|---|"]
    mpc = [g for g in result["groups"] if g["policy"] == "mpc"]
    for noise in sorted({g["noise_std_m"] for g in mpc}):
        gs = [g for g in mpc if g["noise_std_m"] == noise]
        its = sorted(n for g in gs for n in g.get("iterations", []) if n is not None)
        n = sum(g["episodes"] for g in gs)
        rows.append(f"| control: MPC on the surrogate plants ({', '.join(g['plant'] for g in gs)}), noise {noise:g} m | "
                    f"reached {sum(g['reached'] for g in gs)}/{n}, median {_f(float(np.median(its)) if its else None, '.0f')} "
                    f"iterations; settled within ±10 µm {sum(g['settled'] for g in gs)}/{n} | reached, {CONTROL['mpc'][0]} iterations |")
    return "\n".join(rows)


def control_fem_headline(result: dict) -> str:
    """The README's line of the MPC on the FEM plants (``make control PRESET=fem``)."""
    gs = [g for g in result["groups"] if g["policy"] == "mpc"]
    its = sorted(n for g in gs for n in g.get("iterations", []) if n is not None)
    worst = max((g["largest_overshoot_m"] or 0.0) for g in gs) if gs else None
    return "\n".join(["| what | ours | paper |", "|---|---|---|",
                      f"| control: MPC on the FEM plants ({len(gs)} setups, 80 % of each one's travel, noise 1e-4 m) | "
                      f"settled {sum(g['settled'] for g in gs)}/{sum(g['episodes'] for g in gs)}, median "
                      f"{_f(float(np.median(its)) if its else None, '.0f')} iterations, at most "
                      f"{_f(None if worst is None else 1e6 * worst, '.1f')} µm past | – (the paper controls surrogates only) |"])


#: block name -> (results file, renderer)
BLOCKS = {
    "fem_speed": ("bench/reference/fem_speed.json", fem_speed),
    "fem_speed_headline": ("bench/reference/fem_speed.json", fem_speed_headline),
    "contact_reference": ("bench/reference/contact_reference.json", contact_reference),
    "headline": ("bench/reference/contact_reference.json", headline),
    "surrogate_table2": ("bench/reference/surrogate_experiments.json", surrogate_table2),
    "surrogate_pairs": ("bench/reference/surrogate_pairs.json", surrogate_pairs),
    "surrogate_headline": ("bench/reference/surrogate_experiments.json", surrogate_headline),
    "control_goals": ("bench/reference/control_surrogate.json", control_goals),
    "control_fem": ("bench/reference/control_fem.json", control_fem),
    "control_headline": ("bench/reference/control_surrogate.json", control_headline),
    "control_fem_headline": ("bench/reference/control_fem.json", control_fem_headline),
    "control_fem_multi": ("bench/reference/control_fem_multi.json", control_fem_multi),
    "inference_calibration": ("bench/reference/inference_calibration.json", inference_calibration),
    "stability": ("bench/reference/stability.json", stability),
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


def pages(root: Path = REPO) -> list[str]:
    """The pages that may carry results blocks: the README and every page of docs/."""
    return ["README.md", *sorted(p.relative_to(root).as_posix() for p in (root / "docs").glob("*.md"))]


def stale_pages(root: Path = REPO) -> list[str]:
    """The pages whose results blocks differ from their files."""
    return [p for p in pages(root) if (root / p).is_file() and render((root / p).read_text(), root) != (root / p).read_text()]


def write_pages(root: Path = REPO) -> list[str]:
    """Rewrite the stale pages; return them."""
    stale = stale_pages(root)
    for p in stale:
        atomic_write(root / p, lambda path, text=render((root / p).read_text(), root): Path(path).write_text(text))
    return stale
