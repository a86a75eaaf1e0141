"""What ``deapull control`` (:mod:`deapull.workflows.control`) shows of a run: the summary
table per policy, plant, noise and task beside the paper's numbers, and the figures: per
plant and noise the coin's position and the voltage per policy (mean and 25–75 % band over
the episodes, the paper's Fig. 6), and the inferred φ with each field's Cramér–Rao bound."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from deapull.control.filters import settle_bound
from deapull.io import atomic_write, markdown_of, table_record
from deapull.paper import CONTROL


def _padded(series: list[np.ndarray]) -> np.ndarray:
    """Episodes of different lengths as one array, each held at its last value."""
    n = max(len(s) for s in series)
    return np.stack([np.concatenate([s, np.full(n - len(s), s[-1])]) for s in series])


def plot_all(out: Path, episodes, target_m: float, tolerance_m: float) -> None:
    """Every figure of a run (its ``control.Episode`` list, the target and its tolerance) into ``out``."""
    import matplotlib  # lazy: matplotlib (~0.5 s) loads only when the figures are drawn
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from deapull.control.plants import DT_S  # lazy: the control stage loads torch
    groups: dict = {}
    for e in episodes:
        groups.setdefault((e.row["plant"], e.row["noise_std_m"]), {}).setdefault(e.row["policy"], []).append(e)
    for (plant, noise), by_policy in groups.items():
        stem = f"{plant.replace(':', '_')}_noise{noise:g}"
        for what, get, ylabel, dt in (("position", lambda e: 1e3 * e.x_m, "coin x [mm]", None),
                                      ("voltage", lambda e: e.V_V, "V [V]", DT_S)):
            fig, ax = plt.subplots(figsize=(7, 4))
            for policy, eps in by_policy.items():
                values = _padded([get(e) for e in eps])
                t = np.arange(values.shape[1]) * (dt or 1)
                ax.plot(t, values.mean(0), label=f"{policy} (mean of {len(eps)})")
                lo, hi = np.percentile(values, [25, 75], axis=0)
                ax.fill_between(t, lo, hi, alpha=0.25)
            if what == "position":
                first = next(iter(by_policy.values()))[0].row.get("setpoints_mm", "")
                target = float(str(first).split(";")[0]) if first else 1e3 * target_m   # the plant's own
                ax.axhline(target, color="k", lw=0.8, ls="--", label=f"x^T = {target:g} mm")
                ax.axhspan(target - 1e3 * tolerance_m, target + 1e3 * tolerance_m, color="0.85")
            ax.set_xlabel("t [s]" if dt else "iteration (Δt = 1 ms)")
            ax.set_ylabel(ylabel)
            ax.set_title(f"{plant}, observation noise {noise:g} m (line: mean, band: 25–75 %; "
                         "finished episodes held)", fontsize=9)
            ax.legend(fontsize=8)
            _save(fig, out / f"{what}_{stem}.png")
        inferring = {p: eps for p, eps in by_policy.items() if eps[0].inferred}
        if inferring:
            fields = sorted({f for eps in inferring.values() for f in eps[0].inferred})
            fig, axes = plt.subplots(len(fields), 1, figsize=(7, 2.5 * len(fields)), squeeze=False)
            truth = next(iter(inferring.values()))[0].row
            for ax, f in zip(axes[:, 0], fields):
                for policy, eps in inferring.items():
                    values = _padded([e.inferred[f] for e in eps if f in e.inferred]).astype(float)
                    values[~np.isfinite(values)] = np.nan          # a bound not yet computed, or inf
                    ax.plot(values.mean(0), label=f"{policy} (mean)")
                    lo, hi = np.percentile(values, [25, 75], axis=0)
                    ax.fill_between(np.arange(values.shape[1]), lo, hi, alpha=0.25)
                true = truth.get(f"true_{f}")
                if true is not None and math.isfinite(true):
                    ax.axhline(true, color="k", ls="--", lw=0.8, label="true")
                if f.startswith("crlb_"):       # the Cramér–Rao bound on the relative error
                    ax.set_yscale("log")
                    ax.axhline(0.1, color="r", ls=":", lw=0.8, label="10 % (the paper's inference error)")
                ax.set_ylabel(f)
                ax.legend(fontsize=8)
            axes[-1, 0].set_xlabel("iteration")
            _save(fig, out / f"inferred_{stem}.png")


def _save(fig, path: Path) -> None:
    import matplotlib.pyplot as plt  # lazy: as in plot_all
    fig.tight_layout()
    atomic_write(path, lambda p: fig.savefig(p, dpi=110, format="png"), suffix=".png")
    plt.close(fig)


def summary_rows(rows: list[dict], tolerance_m: float) -> list[dict]:
    """One row per (policy, plant, noise): counts, medians and the paper's numbers, episode 1 apart from
    the repeats (what a learning policy carries over shows there), and the
    information bound: the episodes that a controller can expect to settle at most in as many
    iterations as each took, knowing the plant's travel only from the observations
    (:func:`~deapull.control.filters.settle_bound`, docs/control.md "What noise allows")."""
    groups = _cells(rows)
    out = []
    for (policy, plant, noise, task), group in groups.items():
        its = [r["iterations_to_target"] for r in group if r["reached"]]
        q = np.percentile(its, [25, 50, 75]) if its else [math.nan] * 3
        paper_its, paper_ms = CONTROL[policy.split("+")[0]]
        overshoot = [r["overshoot_m"] for r in group if r.get("overshoot_m") is not None]
        beyond = all(str(r.get("status", "")).startswith("unreachable") for r in group)
        first = [r for r in group if r.get("episode", 0) == 0]
        later = [r for r in group if r.get("episode", 0) > 0]
        later_its = [r["iterations_to_target"] for r in later if r["settled"]]
        out.append({"policy": policy, "plant": plant, "noise": noise, "task": task,
                    "first": "–" if not first or beyond else
                    f"{'settled' if first[0]['settled'] else 'reached' if first[0]['reached'] else 'not reached'}"
                    f"{' in ' + str(first[0]['iterations_to_target']) if first[0]['reached'] else ''}",
                    "later": "–" if not later or beyond else
                    f"{len(later_its)}/{len(later)}" + (f", {np.median(later_its):.0f}" if later_its else ""),
                    "reached": "unreachable" if beyond else f"{len(its)}/{len(group)}",
                    "settled": f"{sum(r['settled'] for r in group)}/{len(group)}",
                    "its": "–" if not its else f"{q[1]:.0f} [{q[0]:.0f}–{q[2]:.0f}]",
                    "error_mm": 1e3 * float(np.median([r["final_abs_error_m"] for r in group])),
                    "overshoot_mm": 1e3 * max(overshoot) if overshoot else math.nan,
                    "ms": float(np.mean([r["ms_per_iteration"] for r in group])),
                    "training": group[0]["training_steps"],
                    "bound": "–" if not its else
                    f"{sum(settle_bound(float(noise), tolerance_m, n) for n in its):.1f}/{len(group)}",
                    "paper_its": paper_its, "paper_ms": paper_ms})
    return out


def _cells(rows: list[dict]) -> dict:
    """The episode rows by (policy, plant, noise, setpoints), in order of first appearance."""
    groups: dict = {}
    for r in rows:
        groups.setdefault((r["policy"], r["plant"], r["noise_std_m"], r.get("setpoints_mm", "")), []).append(r)
    return groups


def summary_counts(rows: list[dict]) -> list[dict]:
    """Per (policy, plant, noise, task), the counts and medians as numbers (the results file
    ``summary.json`` the docs' control table is generated from)."""
    groups = _cells(rows)
    out = []
    for (policy, plant, noise, task), group in groups.items():
        done = [r for r in group if not str(r.get("status", "")).startswith("unreachable")]
        its = [r["iterations_to_target"] for r in done if r["reached"]]
        settled_its = [r["iterations_to_target"] for r in done if r["settled"]]
        later = [r for r in done if r.get("episode", 0) > 0]
        later_its = [r["iterations_to_target"] for r in later if r["settled"]]
        overshoot = [r["overshoot_m"] for r in done if r.get("overshoot_m") is not None]
        median = (lambda v: float(np.median(v)) if v else None)  # noqa: E731
        entry = {"policy": policy, "plant": plant, "noise_std_m": float(noise), "task": task,
                    "episodes": len(done), "unreachable": len(group) - len(done), "reached": len(its),
                    "settled": len(settled_its), "median_iterations": median(its),
                    "settled_within_100": sum(n <= 100 for n in settled_its),
                    "median_settled_iterations": median(settled_its),
                    "later_episodes": len(later), "later_settled": len(later_its),
                    "later_median_iterations": median(later_its),
                    "largest_overshoot_m": max(overshoot) if overshoot else None,
                    "iterations": [r["iterations_to_target"] if r["reached"] else None
                                   for r in sorted(done, key=lambda r: r.get("episode", 0))]}
        if ";" in str(task):   # a multi-setpoint task: each episode's setpoints settled and iterations to each
            entry["setpoints_settled"] = [int(r["setpoints_settled"]) for r in done]
            entry["iterations_per_setpoint"] = [[None if n in ("None", None) else int(n)
                                                 for n in str(r["iterations_per_setpoint"]).split(";")] for r in done]
        out.append(entry)
    return out


#: the control table's columns (header, key of :func:`summary_rows`, format)
TABLE_COLUMNS = (
    ("policy", "policy", "s"), ("plant", "plant", "s"), ("noise std (m)", "noise", "g"),
    ("setpoints (mm)", "task", "s"), ("reached", "reached", "s"), ("settled", "settled", "s"),
    ("iterations to target, median [25–75 %]", "its", "s"),
    ("episode 1", "first", "s"), ("episodes 2–N settled, median iterations", "later", "s"),
    ("information bound: settled at most in those iterations", "bound", "s"),
    ("final abs(x − x^T) median (mm)", "error_mm", ".3g"), ("largest overshoot (mm)", "overshoot_mm", ".3g"),
    ("ms / iteration", "ms", ".3g"), ("training env steps", "training", "d"), ("paper: iterations", "paper_its", "s"),
    ("paper: ms / iteration", "paper_ms", "g"))


def summary_record(rows: list[dict], tolerance_m: float) -> dict:
    """The table of :func:`summary_rows` as data (:func:`deapull.io.table_record`), for summary.json."""
    return table_record(summary_rows(rows, tolerance_m), TABLE_COLUMNS)


def summary_table(rows: list[dict], tolerance_m: float) -> str:
    """Markdown: per policy, plant and noise, beside the paper's iterations and time."""
    return markdown_of(summary_record(rows, tolerance_m))


