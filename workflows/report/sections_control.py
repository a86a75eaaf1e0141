"""The report's control section: closed-loop episodes (the paper's Fig. 6), online
inference of φ and the MPC step beside mpc.pytorch."""
from __future__ import annotations

import json
import re

import numpy as np

from deapull.paper import (CONTROL, CONTROL_NOISE_M, INFER_ERROR_PCT, INFER_MASS_ITERATIONS,
                           INFER_MU_B_ITERATIONS, MPC_S_PER_ITERATION)
from deapull.workflows.report.document import Claim, Report, Section, Table
from deapull.workflows.report.plots import BAND_PERCENTILES, plot_bands
from deapull.workflows.report.tabular import csv_text, fmt, num, read_csv, run_config

#: the band CSV keeps every k-th iteration (and the last), k chosen so a line has at most this many rows
BAND_CSV_ROWS = 250
BAND_COLUMNS = ("plant", "noise_std_m", "policy", "iteration", "episodes", "running",
                *(f"x_p{q}_mm" for q in BAND_PERCENTILES))


def section_control(rep: Report) -> Section:
    sec = Section("control", "Control and inference (the paper's Fig. 6, §VI-B/C)")
    inputs = rep.inputs
    csv_path = inputs.control / "control.csv"
    if rep.found(csv_path, sec, "the closed-loop episodes", "control"):
        rows = read_csv(csv_path)
        run_json = inputs.control / "run.json"
        if run_json.is_file():
            rep.source(run_json, sec)
        sec.p("The task (`docs/control.md`): push the coin to x^T = −1 mm in 1 ms steps, |ΔV| ≤ the same limit "
              "for every policy; success is |x − x^T| < 0.01 mm on the true state; 10 episodes per policy, plant "
              "and observation noise. Paper, Fig. 6: C2, mean of 10 episodes with the 25–75 % band; MPC reaches "
              f"the target in {CONTROL['mpc'][0]} iterations, SAC {CONTROL['sac'][0]}, PD {CONTROL['pd'][0]}, the "
              f"heuristic {CONTROL['heur'][0]} (with noise {CONTROL_NOISE_M * 1e3:g} mm).")
        noises = sorted({float(r["noise_std_m"]) for r in rows})
        plants = list(dict.fromkeys(r["plant"] for r in rows))
        policies = list(dict.fromkeys(r["policy"] for r in rows))
        paper_plant = "surrogate:C2" if "surrogate:C2" in plants else plants[0]
        f_rows, anchors = [], []
        for pol in policies:
            paper_it, paper_ms = CONTROL.get(pol.split("+")[0], ("–", None))
            for plant in sorted(plants, key=lambda p: p != paper_plant):       # the paper's plant first
                cells = [pol, plant, paper_it, fmt(paper_ms, "g")]
                for noise in noises:
                    sel = [r for r in rows if r["policy"] == pol and r["plant"] == plant
                           and float(r["noise_std_m"]) == noise]
                    its = [num(r, "iterations_to_target") for r in sel if r.get("reached") in ("True", "1")]
                    its = [i for i in its if i is not None]
                    cells.append(f"{np.median(its):.0f} ({len(its)}/{len(sel)})" if its else f"– (0/{len(sel)})")
                ms = [num(r, "ms_per_iteration") for r in rows if r["policy"] == pol and r["plant"] == plant]
                ms = [m for m in ms if m is not None]
                cells.append(fmt(float(np.median(ms)) if ms else None, ".3g"))
                f_rows.append(cells)
                anchors.append(f"control-{pol}" if plant == paper_plant else f"control-{pol}-{plant}")
        heads = (["policy", "plant", "paper: iterations", "paper: ms / it"] + [f"noise {n:g} m" for n in noises]
                 + ["ours: ms / it"])
        sec.table(Table(heads, f_rows, anchors, caption="Iterations to target, median (reached / episodes), ours "
                                                         "beside the paper's (its Fig. 6: f_s,2 = surrogate:C2, "
                                                         f"noise {CONTROL_NOISE_M:g} m)"))
        paper_noise = CONTROL_NOISE_M if CONTROL_NOISE_M in noises else noises[-1]
        for pol in policies:
            sel = [r for r in rows if r["policy"] == pol and r["plant"] == paper_plant
                   and float(r["noise_std_m"]) == paper_noise]
            its = [num(r, "iterations_to_target") for r in sel if r.get("reached") in ("True", "1")]
            its = [i for i in its if i is not None]
            ours = (f"median {np.median(its):.0f} ({len(its)}/{len(sel)} reached)" if its
                    else f"never reached (0/{len(sel)})")
            paper_it = CONTROL.get(pol.split("+")[0], ("–",))[0]
            rep.claims.append(Claim(f"Iterations to target, {pol} ({paper_plant}, noise {paper_noise:g} m)",
                                    paper_it, ours, f"#control-{pol}",
                                    _fewer(float(np.median(its)) if its else None, paper_it)))
        summary = inputs.control / "summary.json"
        table = json.loads(summary.read_text()).get("table") if summary.is_file() else None
        if table:
            rep.source(summary, sec)
            sec.table(Table(table["headers"], table["rows"], caption="Per policy, plant and noise (`summary.json` of "
                                                                     "the run)"))
        else:
            sec.lack(f"the run's table in `{summary}` (written by `deapull control`; re-run it)", "control")
        _bands(rep, sec, inputs.control)
        for pattern, cap in (("position_*.png", "coin position, mean and 25–75 % band per policy (Fig. 6)"),
                             ("voltage_*.png", "voltage per policy"),
                             ("inferred_*.png", "inferred φ per iteration beside the true value")):
            # the paper's Fig. 6 first: plant f_s,2 (C2), the paper's noise (largest first)
            for png in sorted(inputs.control.glob(pattern),
                              key=lambda p: ("_C2_" not in p.name, _noise_key(p.stem), p.stem)):
                sec.img(rep.copy_image(png, f"control_{png.name}"), f"`{png.stem}`: {cap}.")
        inf_rows = []
        for pol in policies:
            for q, label in (("mass_kg", "m_c"), ("mu_b", "μ_b"), ("mu_t", "μ_t")):
                errs = [abs(num(r, f"inferred_{q}") / num(r, f"true_{q}") - 1) * 100 for r in rows if r["policy"] == pol
                        and num(r, f"inferred_{q}") is not None and num(r, f"true_{q}")]
                if errs:
                    inf_rows.append([pol, label, f"{np.median(errs):.3g}", f"{max(errs):.3g}", str(len(errs))])
        if inf_rows:
            sec.table(Table(["policy", "φ", "median error %", "max error %", "episodes"], inf_rows,
                            [f"infer-{r[0]}-{i}" for i, r in enumerate(inf_rows)],
                            caption="Online inference at the end of the episodes (paper: m_c within "
                                    f"{INFER_ERROR_PCT:g} % after {INFER_MASS_ITERATIONS:,} iterations, μ_b within "
                                    f"{INFER_MU_B_ITERATIONS})"))
            mc = [r for r in inf_rows if r[1] == "m_c"]
            if mc:
                rep.claims.append(Claim("Inferred m_c",
                                        f"≤ {INFER_ERROR_PCT:g} % error within {INFER_MASS_ITERATIONS:,} iterations",
                                        f"median {mc[0][2]} % ({mc[0][0]})", f"#infer-{mc[0][0]}-0"))
        else:
            sec.p("No policy in this run inferred φ (the MPC does): `make control` runs all four.")
    bench = inputs.bench_control / "bench_control.json"
    if rep.found(bench, sec, "the MPC step beside mpc.pytorch", "bench-control"):
        b = json.loads(bench.read_text())
        b_rows = [[r.get("solver", ""), fmt(r.get("median_ms"), ".3g"), fmt(r.get("median_ms_per_iteration"), ".3g"),
                   fmt(r.get("mean_cost"), ".5g")] for r in b.get("rows", [])]
        sec.table(Table(["solver", "median ms / MPC step", "ms / iteration", "mean cost"], b_rows,
                        [f"mpc-{i}" for i in range(len(b_rows))],
                        caption=f"MPC step (horizon {b.get('horizon')}, {b.get('iterations')} iterations), ours beside "
                                "mpc.pytorch on the same problem; paper: "
                                f"{b.get('paper_s', MPC_S_PER_ITERATION)} s per iteration"))
        if b.get("mpc_pytorch_skipped"):
            sec.p(f"mpc.pytorch was not run: {b['mpc_pytorch_skipped']}")
        if b_rows:
            rep.claims.append(Claim("MPC time per iteration", f"{MPC_S_PER_ITERATION:g} s (mpc.pytorch)",
                                    f"{b_rows[0][1]} ms ({b_rows[0][0]})", "#mpc-0"))
    return sec


def section_control_fem(rep: Report) -> Section:
    """The MPC on the FEM plant of every setup (``make control-fem``) and the multi-setpoint task."""
    sec = Section("control-fem", "The closed loop on the FEM (beyond the paper)")
    folder = rep.inputs.control_fem
    csv_path = folder / "control.csv"
    if not rep.found(csv_path, sec, "the MPC on the FEM plants", "control-fem"):
        return sec
    rep.source(csv_path, sec)
    sec.p("The offset-free MPC (`docs/control.md`) on the FEM stepped online (`advance(V, 1 ms)`, each setup's "
          "scene at the run's `--fidelity` and `--set`, in its run.json), observation noise 0.1 mm: it plans on f_a, estimates f_a's gain error with the "
          "position and holds V once the estimate is inside the window. The paper runs control on its surrogates "
          "only. Settled = the true position stays within ±0.01 mm for the whole hold after the first success.")
    rows = read_csv(csv_path)
    runs = [("Single target", folder)]
    multi = folder / "multi" / "control.csv"
    if multi.is_file():
        rep.source(multi, sec)
        rows += read_csv(multi)
        runs.append(("Multi-setpoint task", folder / "multi"))
    for label, run_folder in runs:
        if (run_folder / "run.json").is_file():
            rep.source(run_folder / "run.json", sec)
            sec.p(f"{label}: {mpc_settings_text(run_config(run_folder))}.")
    t_rows, anchors = [], []
    for i, r in enumerate(rows):
        anchors.append(f"control-fem-{i}")
        if r.get("status", "").startswith("unreachable"):      # left out before its episode (--unreachable report)
            t_rows.append([r["plant"], r.get("setpoints_mm", ""), "–", "–", "unreachable", "–", "–", "–", "–"])
            continue
        t_rows.append([r["plant"], r.get("setpoints_mm", ""), r.get("iterations_per_setpoint") or
                       r.get("iterations_to_target") or "–", f"{r.get('setpoints_settled', '')}",
                       "yes" if r.get("settled") in ("True", "1") else "no",
                       fmt(1e3 * (num(r, "overshoot_m") or 0.0), ".3f"),
                       fmt(1e3 * (num(r, "final_abs_error_m") or 0.0), ".4f"),
                       fmt(num(r, "plant_ms_per_step"), ".3g"), fmt(num(r, "episode_wall_s"), ".3g")])
    sec.table(Table(["plant", "setpoints (mm)", "iterations per setpoint", "setpoints settled", "settled",
                     "overshoot (mm)", "final abs error (mm)", "FEM ms / step", "episode wall (s)"], t_rows, anchors,
                    caption="One episode per plant; the row with setpoints −0.5;−1;−0.7 is the multi-setpoint "
                            "task (push, push, pull back)"))
    beyond = [r for r in rows if r.get("status", "").startswith("unreachable")]
    ran = [r for r in rows if r not in beyond]
    settled = sum(r.get("settled") in ("True", "1") for r in ran)
    for r in beyond:
        sec.p(f"{r['plant']} is left out: {r['status']}.")
    rep.claims.append(Claim("The MPC on the FEM plant (noise 0.1 mm)", "not run (control on the surrogates only)",
                            f"settled in {settled}/{len(ran)} episodes" +
                            (f"; {len(beyond)} plant(s) cannot reach the target ({', '.join(r['plant'] for r in beyond)})"
                             if beyond else ""), "#control-fem-0", outcome="beyond the paper"))
    for png in sorted(folder.glob("position_*.png")) + sorted((folder / "multi").glob("position_*.png")):
        sec.img(rep.copy_image(png, f"control_fem_{png.parent.name}_{png.name}"), f"`{png.stem}`: coin position.")
    return sec


def mpc_settings_text(config: dict) -> str:
    """How a run's MPC moved V, from its ``run.json`` config (``control`` with its ``mpc`` table)."""
    mpc = config.get("mpc") or {}
    estimator = mpc.get("estimator") or {}
    parts = []
    rate = mpc.get("rate_V") or 0.0
    plant = config.get("dv_max_V", 5.0)
    parts.append(f"{plant:g} V per step while f_a says the coin stands, then {rate:g} V per step "
                 f"(`mpc.rate_V`)" if rate > 0 else f"up to the plant's {plant:g} V per step")
    if (mpc.get("approach_m") or 0.0) > 0:
        creep = mpc.get("creep_V") or 0.5
        parts.append(f"slowing within {1e3 * mpc['approach_m']:g} mm of the target (`mpc.approach_m`) "
                     f"down to {creep:g} V per step (`mpc.creep_V`)")
    if (mpc.get("standoff_stds") or 0.0) > 0:
        parts.append(f"aiming {mpc['standoff_stds']:g} stds of its estimate, less the tolerance, short of the "
                     "target, closing as the estimate averages down (`mpc.standoff_stds`)")
    if (estimator.get("innovation_window") or 0) > 0:
        parts.append(f"its bias filter checking the mean of its last {estimator['innovation_window']:d} "
                     "innovations (`mpc.estimator.innovation_window`)")
    if mpc.get("reach_gate") is False and ((mpc.get("standoff_stds") or 0.0) > 0
                                          or (mpc.get("approach_m") or 0.0) > 0):
        parts.append("keeping the stand-off and the slow approach also where f_a puts the target at the edge of "
                     "the coin's reach (`mpc.reach_gate = false`)")
    if config.get("mpc_phi") == "prior":
        parts.append("planning at the coin prior's median φ, no online inference (`mpc_phi = \"prior\"`)")
    if config.get("mpc_model"):
        parts.append(f"f_a from `{config['mpc_model']}`")
    return "; ".join(parts)


def bands(series: list) -> dict:
    """Percentiles across episodes at every iteration (:data:`BAND_PERCENTILES`, ``p10`` ... keys);
    an episode that finished early is held at its last value (as the run's own figures);
    ``running``: how many episodes still ran at that iteration."""
    n = max(len(s) for s in series)
    held = np.stack([np.concatenate([s, np.full(n - len(s), s[-1])]) for s in series])
    out = {f"p{q}": v for q, v in zip(BAND_PERCENTILES, np.percentile(held, BAND_PERCENTILES, axis=0))}
    out["running"] = np.array([sum(len(s) > i for s in series) for i in range(n)])
    out["episodes"] = len(series)
    return out


def trace_bands(path) -> dict:
    """``traces.npz`` of ``deapull control`` (keys ``policy|plant|noise|episode|x_m``) as
    {(plant, noise): {policy: bands of x in mm}}, plants and policies in the run's order."""
    groups: dict = {}
    with np.load(path, allow_pickle=False) as npz:
        for key in npz.files:
            parts = key.split("|")
            if len(parts) != 5 or parts[4] != "x_m":
                continue
            policy, plant, noise, episode = parts[:4]
            groups.setdefault((plant, float(noise)), {}).setdefault(policy, []).append(
                (int(episode), 1e3 * np.asarray(npz[key], dtype=float)))
    return {k: {pol: bands([x for _, x in sorted(eps, key=lambda e: e[0])]) for pol, eps in by.items()}
            for k, by in groups.items()}


def band_rows(panels: dict, max_rows: int = BAND_CSV_ROWS) -> list[dict]:
    """The bands as CSV rows: every k-th iteration and the last (k so a line has ≤ ``max_rows``)."""
    rows = []
    for (plant, noise), by in panels.items():
        for policy, b in by.items():
            n = len(b["running"])
            step = max(1, -(-n // max_rows))
            for i in sorted(set(range(0, n, step)) | {n - 1}):
                rows.append({"plant": plant, "noise_std_m": noise, "policy": policy, "iteration": i,
                             "episodes": b["episodes"], "running": int(b["running"][i]),
                             **{f"x_p{q}_mm": float(b[f"p{q}"][i]) for q in BAND_PERCENTILES}})
    return rows


def _bands(rep: Report, sec: Section, folder) -> None:
    """The Fig. 6-style figure from the run's traces, with its CSV."""
    path = folder / "traces.npz"
    if not path.is_file():
        sec.p(f"No per-episode traces (`{path}`): `make control` writes them; the bands per policy and noise "
              "are drawn from them.")
        return
    rep.source(path, sec)
    panels = trace_bands(path)
    if not panels:
        sec.p(f"`{path}` holds no coin positions (keys `policy|plant|noise|episode|x_m`).")
        return
    config = run_config(folder)
    target = config.get("target_m") if not config.get("setpoints_m") else None
    tol = config.get("tolerance_m")
    plot_bands(panels, rep.img / "control_bands.png", 1e3 * target if target is not None else None,
               1e3 * tol if tol else None)
    lo, hi = BAND_PERCENTILES[0], BAND_PERCENTILES[-1]
    sec.img("img/control_bands.png", f"The paper's Fig. 6 per plant (rows) and observation noise (columns): the "
            f"coin's x per policy, median line and {lo}–{hi} % band across the episodes (an episode that finished is "
            "held at its last position; the CSV's `running` column says how many still ran). The paper shows the "
            "mean with a 25–75 % band on f_s,2 only.")
    sec.data("bands", csv_text(band_rows(panels), BAND_COLUMNS),
             f"CSV of the bands (x in mm: {lo} %, median, {hi} % per iteration; every k-th iteration and the last, "
             f"at most {BAND_CSV_ROWS} rows per line)")


def _fewer(ours, paper: str) -> str:
    """Our iteration count against the paper's wording ("≤ N" or "~N"): fewer, similar or more."""
    digits = re.sub(r"[^0-9]", "", paper)
    if ours is None or not digits:
        return "never reached" if ours is None and digits else ""
    ref = float(digits)
    return "fewer" if ours < 0.7 * ref else ("more" if ours > 1.3 * ref else "similar")


def _noise_key(stem: str) -> float:
    m = re.search(r"noise([0-9.e+-]+)$", stem)
    try:
        return -float(m.group(1)) if m else 0.0
    except ValueError:
        return 0.0
