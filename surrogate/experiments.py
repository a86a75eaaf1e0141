"""The paper's six sliding experiment sets (§VI-A, Table II) for every model.

Set i (i = 1..6) trains on C_i, early-stops on C_{i+1} and tests a recursive 1 s rollout
on C_{i+2}. Every model kind is trained and evaluated on every set; the results are
written as ``experiments.csv`` (one row per set and model), ``experiments.json``,
``table.txt`` (a Table II with the paper's numbers beside ours, and the per-set errors),
``x_error_boxplot.png`` (|x error| per set and model, the paper's Fig. 6) and
``rollouts.png`` (x(t) of the FEM and of each model on each test setup). Each trained
model is kept under ``set<i>/<kind>/``. With ``restarts`` > 1 each model is the best of that
many seeds on the set's validation setup (its rollout x error; :func:`surrogate.train.train`):
the rows record the kept seed and every restart's validation score, never the test setup's.
"""
from __future__ import annotations

import logging
import math
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from deapull.errors import InputError
from deapull.io import write_csv, write_json, write_text
from deapull.paper import ABAQUS_S, TABLE2
from deapull.surrogate import card, ensemble, store
from deapull.surrogate.data import DatasetError, load_sweep
from deapull.surrogate.evaluate import METRICS, evaluate
from deapull.surrogate.models import KINDS
from deapull.surrogate.rollout import OutOfRangeWarning
from deapull.surrogate.train import TrainConfig, train

log = logging.getLogger(__name__)

SETS = {i: (f"C{i}", f"C{i + 1}", f"C{i + 2}") for i in range(1, 7)}
#: Table II of the paper (MAE over the six test setups) and its §VI-A timings (deapull.paper)
PAPER = TABLE2
PAPER_FEM_S = ABAQUS_S
COLUMNS = ("repeat", "set", "train", "val", "test", "model", "mae_x_m", "mae_u_m_s", "mae_Fx_N", "mae_Fy_N",
           "x_error_pct_travel", "max_abs_x_error_m", "final_x_error_m", "travel_m", "rollout_ms", "engine",
           "diverged", "best_epoch", "epochs_run", "train_time_s", "out_of_range_warnings", "seed", "restarts",
           "val_x_error_pct_travel", "val_loss", "restart_seeds", "restart_val_x_error_pct", "restart_val_loss",
           "band_k", "band_coverage")


#: the kinds the sets run by default: those one training coin identifies (not f-patch)
SET_KINDS = tuple(k for k, cls in KINDS.items() if cls.training_coins == 1)


def run(data_dir: str | Path, out_dir: str | Path, base: TrainConfig, kinds=SET_KINDS,
        sets=tuple(SETS), restarts: dict | None = None, repeats: int = 1) -> list[dict]:
    """Train and evaluate every model kind on every set; write the tables and plots.

    Parameters
    ----------
    data_dir : str or pathlib.Path
        Folder with ``C1.nc`` ... ``C8.nc``.
    out_dir : str or pathlib.Path
        Output folder (created).
    base : TrainConfig
        Training settings shared by all runs (its ``kind`` is replaced per model).
    kinds : sequence of str
        Model kinds to run.
    sets : sequence of int
        Which of the six sets to run.
    restarts : dict, optional
        Restarts per kind (``base.restarts`` for a kind not in it).
    repeats : int
        Independent repeats of every (set, kind): repeat r trains the seeds ``base.seed`` +
        r·restarts onward; the tables show the mean over repeats and its spread. Repeat 0's
        models are kept under ``set<i>/<kind>/``, the others under ``repeats/<r>/set<i>/<kind>/``.

    Returns
    -------
    list of dict
        One row per (repeat, set, model), the columns of :data:`COLUMNS`.
    """
    kinds = list(kinds)
    for i in sets:
        if i not in SETS:
            raise InputError(f"set {i} does not exist; the paper's sets are 1..6")
    for kind in kinds:
        if kind not in KINDS:
            raise InputError(f"model {kind!r} is not a model; choose from {', '.join(KINDS)}")
    if repeats < 1:
        raise InputError(f"--repeats {repeats}: must be a whole number of at least 1")
    needed = sorted({name for i in sets for name in SETS[i]}, key=lambda n: int(n[1:]))
    data = load_sweep(data_dir, needed)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows, curves, bands = [], {}, {}
    jobs = [(r, i, kind) for r in range(repeats) for i in sets for kind in kinds]
    for r, i, kind in tqdm(jobs, desc="experiments", unit="model", disable=None):
        train_name, val_name, test_name = SETS[i]
        n = (restarts or {}).get(kind, base.restarts)
        result = train(replace(base, kind=kind, restarts=n, seed=base.seed + r * n), [data[train_name]],
                       data[val_name])
        test = data[test_name]
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", OutOfRangeWarning)
            ev = evaluate(result.model, test)
        for w in caught:
            log.info("set %d: %s", i, w.message)
        folder = out / f"set{i}" / kind if r == 0 else out / "repeats" / str(r) / f"set{i}" / kind
        store.save(result.model, folder, result.summary(), result.history, test=ev.metrics)
        row = {**{k: ev.metrics.get(k) for k in COLUMNS}, "repeat": r, "set": i, "train": train_name,
               "val": val_name, "test": test_name, "model": kind, "best_epoch": result.best_epoch,
               "epochs_run": len(result.history), "train_time_s": result.wall_time_s,
               "out_of_range_warnings": len(caught), **restart_columns(result)}
        if len(result.members) >= 2:
            k = ensemble.calibrate(result.members, result.val_sets, result.phis)
            b = ensemble.band(result.members, k, test, result.model.phi_of(test))
            row["band_k"], row["band_coverage"] = k, b.coverage(test.x)
            if r == 0:
                ensemble.save(result, folder, k)
                bands[(i, kind)] = b
        rows.append(row)
        if r == 0:
            curves[(i, kind)] = ev
    text = summary_table(rows, kinds) + "\n\n" + per_set_table(rows, kinds)
    write_text(out / "table.txt", text + "\n")
    write_csv(out / "experiments.csv", rows, COLUMNS)
    write_json(out / "experiments.json", {"rows": rows, "paper": PAPER, "paper_fem_s": PAPER_FEM_S,
                                          "repeats": repeats, "band_level": ensemble.LEVEL,
                                          "fem_wall_time_s": {n: d.wall_time_s for n, d in data.items()},
                                          "config": {k: v for k, v in vars(base).items() if k != "kind"}}, indent=2)
    write_json(out / SUMMARY, summary(rows, kinds, data), indent=2)
    plot_boxes(curves, kinds, sets, out / "x_error_boxplot.png")
    plot_rollouts(curves, kinds, sets, out / "rollouts.png", bands)
    plot_coin_share(data, out / "coin_share.png")
    return rows


def plot_coin_share(data: dict, path: Path) -> Path | None:
    """What a training coin may never show: the coin's speed as a share of its contact patch's
    (u / patch_vx, the FEM's traction-weighted speed of the DEA points touching the coin) against
    the coin's lag behind the tip's free-end face (tip_ux − x), for every coin whose dataset records
    them. A coin whose share stays near 1 is dragged along; one whose share falls to 0 stands
    while the tip slides over it."""
    import matplotlib  # lazy: matplotlib (~0.5 s) loads only when a figure is drawn
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from deapull import dataset
    curves = {}
    for name, d in data.items():
        try:
            run = dataset.read(d.path, ("t", "x", "u", "V"), optional=("patch_vx", "tip_ux"))
        except DatasetError:
            continue
        c = run.columns
        if "patch_vx" not in c or "tip_ux" not in c:
            continue
        sliding = (np.abs(c["patch_vx"]) > 1e-5) & (c["V"] > 0.5 * c["V"].max())
        share = np.where(sliding, c["u"] / np.where(sliding, c["patch_vx"], 1.0), np.nan)
        curves[name] = (1e3 * np.abs(c["tip_ux"] - c["x"]), share, d)
    if not curves:
        return None
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for j, (name, (lag, share, d)) in enumerate(curves.items()):
        ax.plot(lag, share, color=f"C{j}", lw=1.2, label=f"{name} (μ_b {d.mu_b:g}, μ_t {d.mu_t:g})")
    ax.set_xlabel("the coin's lag behind the tip's free-end face (mm)")
    ax.set_ylabel("coin speed / contact patch speed")
    ax.set_title("upper half of the ramp: a coin whose share falls stands while the tip slides over it", fontsize=8)
    ax.set_ylim(-0.1, 1.2)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


#: the results file of a run (``deapull experiments --publish DIR`` copies it to DIR/surrogate_experiments.json)
SUMMARY = "summary.json"
SUMMARY_KEYS = ("mae_x_m", "mae_u_m_s", "mae_Fx_N", "mae_Fy_N", "x_error_pct_travel", "rollout_ms")


def summary(rows: list[dict], kinds, data: dict) -> dict:
    """The run's results file: Table II (mean over the sets, mean and std over repeats, beside the
    paper's), each set's errors and ensemble coverage, how many sets each f leads on, and the
    fidelity of the data."""
    sets = sorted({r["set"] for r in rows})
    out = {"repeats": len({r.get("repeat", 0) for r in rows}), "sets": sets, "kinds": list(kinds),
           "labels": {k: _label(k) for k in kinds}, "band_level": ensemble.LEVEL, "paper": PAPER,
           "data": {"fidelity": sorted({card.fidelity_label(d.fidelity) for d in data.values()}),
                    "fidelity_id": sorted({d.fidelity_id for d in data.values()})},
           "table2": {k: {key: _pair(_mean_spread(rows, k, key)) for key in SUMMARY_KEYS} for k in kinds},
           "diverged": {k: sum(r["diverged"] for r in rows if r["model"] == k) for k in kinds},
           "per_set": {str(i): {"train_val_test": list(SETS[i]),
                                **{k: {key: _pair(_set_value(rows, i, k, key)[:2]) for key in
                                       ("mae_x_m", "x_error_pct_travel", "band_coverage")}
                                   | {"diverged": _set_value(rows, i, k, "mae_x_m")[2]} for k in kinds}}
                       for i in sets}}
    baselines = [k for k in kinds if not KINDS[k].physics]
    out["ahead"] = {f_kind: _ahead(rows, f_kind, baselines, sets) if baselines else None
                    for f_kind in kinds if KINDS[f_kind].physics}
    cover = {k: [r["band_coverage"] for r in rows if r["model"] == k and r.get("band_coverage") is not None]
             for k in kinds}
    out["band_coverage"] = {k: {"mean": float(np.mean(v)), "min": float(min(v)), "rollouts": len(v)}
                            for k, v in cover.items() if v}
    return out


def restart_columns(result) -> dict:
    """The kept seed and every restart's validation scores, as columns of a row (lists as
    ``;``-separated text, in seed order; a diverged validation rollout scores ``inf``, and
    None where the kept one did)."""
    def joined(key):
        return ";".join(f"{r[key]:.6g}" if isinstance(r[key], float) else str(r[key]) for r in result.restarts)
    err = result.val_x_error_pct
    return {"seed": result.seed, "restarts": len(result.restarts),
            "val_x_error_pct_travel": err if math.isfinite(err) else None,
            "val_loss": result.best_val_loss, "restart_seeds": joined("seed"),
            "restart_val_x_error_pct": joined("val_x_error_pct"), "restart_val_loss": joined("best_val_loss")}


def _label(kind: str) -> str:
    return KINDS[kind].label


def _mean_spread(rows: list[dict], kind: str, key: str) -> tuple:
    """(mean over repeats, standard deviation over repeats) of each repeat's mean of ``key`` over
    the sets where ``kind`` did not diverge; (None, None) if none."""
    per_repeat = []
    for r in sorted({row.get("repeat", 0) for row in rows}):
        values = [row[key] for row in rows if row["model"] == kind and row.get("repeat", 0) == r
                  and row.get(key) is not None and not row["diverged"]]
        if values:
            per_repeat.append(float(np.mean(values)))
    if not per_repeat:
        return None, None
    return float(np.mean(per_repeat)), float(np.std(per_repeat))


def _grid(lines: list[list[str]]) -> str:
    widths = [max(len(line[i]) for line in lines) for i in range(len(lines[0]))]
    return "\n".join("  ".join(c.ljust(w) if j == 0 else c.rjust(w) for j, (c, w) in enumerate(zip(line, widths)))
                     for line in lines)


def _with_spread(mean, spread, scale: float, repeats: int) -> str:
    if mean is None:
        return "-"
    return f"{mean / scale:.3g}" + (f" ± {spread / scale:.2g}" if repeats > 1 else "")


def summary_table(rows: list[dict], kinds=SET_KINDS) -> str:
    """Table II: mean over the sets run of each error, ours beside the paper's; with repeats, the
    mean over repeats ± its standard deviation.

    Rollouts that diverged are left out of the means and counted in the last row.
    """
    keys = ("mae_x_m", "mae_u_m_s", "mae_Fx_N", "mae_Fy_N", "x_error_pct_travel", "rollout_ms")
    repeats = len({r.get("repeat", 0) for r in rows})
    head = ["mean over sets"] + [f"{_label(k)}" for k in kinds] + [f"paper {_label(k)}" for k in kinds
                                                                   if any(k in PAPER[q] for q in PAPER)]
    paper_kinds = [k for k in kinds if any(k in PAPER[q] for q in PAPER)]
    lines = [head]
    for key in keys:
        label, unit, scale = METRICS[key]
        cells = [f"{label} [{unit}]"]
        for kind in kinds:
            cells.append(_with_spread(*_mean_spread(rows, kind, key), scale, repeats))
        for kind in paper_kinds:
            v = PAPER.get(key, {}).get(kind)
            cells.append("-" if v is None else f"{v / scale:.3g}")
        lines.append(cells)
    lines.append(["diverged rollouts"] + [str(sum(r["diverged"] for r in rows if r["model"] == k)) for k in kinds]
                 + ["-"] * len(paper_kinds))
    n_sets = len({r["set"] for r in rows})
    return (f"Simulation error of a recursive 1 s rollout on the test setup, mean over {n_sets} set(s)"
            + (f", mean ± std over {repeats} repeats of independent seeds" if repeats > 1 else "") + "\n"
            f"(paper: Table II, ABAQUS FEM 1 s in {PAPER_FEM_S:.0f} s; paper timings are of its own code)\n"
            + _grid(lines))


def _set_value(rows: list[dict], i: int, kind: str, key: str) -> tuple:
    """(mean over repeats of ``key`` on set ``i``, its std, rollouts that diverged, repeats)."""
    mine = [r for r in rows if r["set"] == i and r["model"] == kind]
    values = [r[key] for r in mine if not r["diverged"] and r.get(key) is not None]
    diverged = sum(r["diverged"] for r in mine)
    if not values:
        return None, None, diverged, len(mine)
    return float(np.mean(values)), float(np.std(values)), diverged, len(mine)


def _ahead(rows: list[dict], f_kind: str, baselines, sets) -> int:
    """On how many ``sets`` ``f_kind``'s MAE of x (mean over repeats) is below every baseline's (a
    set where a model always diverged counts as infinite)."""
    def mae(i, kind):
        mean = _set_value(rows, i, kind, "mae_x_m")[0]
        return math.inf if mean is None else mean
    return sum(all(mae(i, f_kind) < mae(i, b) for b in baselines) for i in sets)


def _pair(value) -> list | None:
    """(mean, std) as a JSON list; None when there is no mean."""
    return None if value[0] is None else [value[0], value[1]]


def _set_cell(rows, i, kind, key, scale) -> str:
    mean, spread, diverged, n = _set_value(rows, i, kind, key)
    if mean is None:
        return "diverged"
    text = f"{mean / scale:.3g}" + (f"±{spread / scale:.2g}" if n > 1 else "")
    return text + (f" ({diverged}/{n} div.)" if diverged else "")


def per_set_table(rows: list[dict], kinds=SET_KINDS) -> str:
    """MAE of x and x error (% of travel) per set and model (means over repeats), the ensemble band's
    coverage of the test run, and which f leads."""
    sets = sorted({r["set"] for r in rows})
    banded = [k for k in kinds if any(r.get("band_coverage") is not None for r in rows if r["model"] == k)]
    head = (["set (train/val/test)"] + [f"{_label(k)} x [1e-4 m]" for k in kinds]
            + [f"{_label(k)} [%]" for k in kinds]
            + [f"{_label(k)} {round(100 * ensemble.LEVEL)} % band covers [%]" for k in banded])
    lines = [head]
    for i in sets:
        r0 = next(r for r in rows if r["set"] == i)
        cells = [f"{i} ({r0['train']}/{r0['val']}/{r0['test']})"]
        cells += [_set_cell(rows, i, k, "mae_x_m", 1e-4) for k in kinds]
        cells += [_set_cell(rows, i, k, "x_error_pct_travel", 1.0) for k in kinds]
        cells += [_set_cell(rows, i, k, "band_coverage", 0.01) for k in banded]
        lines.append(cells)
    verdicts = []
    baselines = [k for k in kinds if not KINDS[k].physics]

    for f_kind in (k for k in kinds if KINDS[k].physics):
        if baselines:
            ahead = _ahead(rows, f_kind, baselines, sets)
            verdicts.append(f"{_label(f_kind)} ahead of {' and '.join(_label(b) for b in baselines)} "
                            f"(MAE x) on {ahead}/{len(sets)} sets")
    for kind in banded:
        cover = [r["band_coverage"] for r in rows if r["model"] == kind and r.get("band_coverage") is not None]
        verdicts.append(f"{_label(kind)}: its {round(100 * ensemble.LEVEL)} % ensemble band covers "
                        f"{100 * np.mean(cover):.1f} % of the test runs' points (mean of {len(cover)} rollouts, "
                        f"lowest {100 * min(cover):.1f} %)")
    return _grid(lines) + ("\n" + "\n".join(verdicts) if verdicts else "")


def plot_boxes(curves: dict, kinds, sets, path: Path) -> Path:
    """Box plots of |x error| over all rollout steps, grouped by set (paper Fig. 6)."""
    import matplotlib  # lazy: matplotlib (~0.5 s) loads only when a figure is drawn
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(2.5 + 1.4 * len(sets), 4.2))
    width = 0.8 / len(kinds)
    for j, kind in enumerate(kinds):
        pos = [i + (j - (len(kinds) - 1) / 2) * width for i in sets]
        data = [np.maximum(curves[(i, kind)].abs_x_error, 1e-9) if not curves[(i, kind)].metrics["diverged"]
                else np.array([]) for i in sets]
        bp = ax.boxplot(data, positions=pos, widths=width * 0.9, patch_artist=True, showfliers=False)
        for box in bp["boxes"]:
            box.set_facecolor(f"C{j}")
        ax.plot([], [], color=f"C{j}", lw=6, label=_label(kind))
    ax.set_yscale("log")
    ax.set_xticks(list(sets))
    ax.set_xticklabels([f"{i}\n{'/'.join(SETS[i])}" for i in sets])
    ax.set_ylabel("|x error| over the 1 s rollout (m, floor 1e-9)")
    ax.set_xlabel("experiment set (train/val/test); no box: the rollout diverged")
    ax.legend(fontsize=8, ncol=len(kinds), loc="lower center", bbox_to_anchor=(0.5, 1.0), frameon=False)
    ax.grid(True, axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_rollouts(curves: dict, kinds, sets, path: Path, bands: dict | None = None) -> Path:
    """x(t) of the FEM and of each model on each set's test setup, with the ensemble band of the
    kinds that have one (``bands[(set, kind)]``)."""
    import matplotlib  # lazy: matplotlib (~0.5 s) loads only when a figure is drawn
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    cols = min(3, len(sets))
    nrows = -(-len(sets) // cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(4.2 * cols, 3.2 * nrows), squeeze=False)
    for ax, i in zip(axes.flat, sets):
        ev0 = curves[(i, kinds[0])]
        ax.plot(ev0.t, ev0.x_fem * 1e3, "k-", lw=2.5, alpha=0.4, label="FEM")
        for j, kind in enumerate(kinds):
            ev = curves[(i, kind)]
            label = _label(kind) + (" (diverged)" if ev.metrics["diverged"] else "")
            ax.plot(ev.t, ev.x_model * 1e3, color=f"C{j}", lw=1, label=label)
            band = (bands or {}).get((i, kind))
            if band is not None:
                ax.fill_between(band.t, band.lower * 1e3, band.upper * 1e3, color=f"C{j}", alpha=0.25, lw=0,
                                label=f"{round(100 * ensemble.LEVEL)} % band ({band.x.shape[0]} restarts)")
        travel_mm = 1e3 * ev0.metrics["travel_m"]
        ax.set_ylim(-1.6 * travel_mm, 0.2 * travel_mm)
        ax.set_title(f"set {i}: test {SETS[i][2]}", fontsize=9)
        ax.legend(fontsize=6)
        ax.set_xlabel("t (s)")
        ax.set_ylabel("x (mm)")
        ax.grid(True, alpha=0.3)
    for ax in list(axes.flat)[len(sets):]:
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
