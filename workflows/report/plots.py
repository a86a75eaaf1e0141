"""The figures the report draws itself (matplotlib, Agg); the DEA pictures are in :mod:`.pictures`."""
from __future__ import annotations

import math
from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.transforms import blended_transform_factory  # noqa: E402

from deapull.io import atomic_write  # noqa: E402
from deapull.paper import ABAQUS_S as ABAQUS_S_LINE  # noqa: E402


def plot_sweep(runs: dict, png: Path) -> Path:
    """x, Fy and Fx against t of every setup's run (``runs``: setup → dataset.Run) on shared axes."""
    fig, ax = plt.subplots(3, 1, figsize=(8, 8.5), sharex=True)
    cmap = plt.get_cmap("tab10")
    for i, (name, run) in enumerate(runs.items()):
        c = run.columns
        style = dict(color=cmap(i % 10), lw=1.2, label=name, ls="-" if i % 2 == 0 else "--")
        ax[0].plot(c["t"], c["x"] * 1e3, **style)
        ax[1].plot(c["t"], c["Fy"] * 1e3, **style)
        ax[2].plot(c["t"], c["Fx"] * 1e3, **style)
    ax[0].set_ylabel("coin x [mm]")
    ax[1].set_ylabel("Fy (pressing) [mN]")
    ax[2].set_ylabel("Fx [mN]")
    ax[2].set_xlabel("t [s] (V = 400 t V)")
    ax[0].legend(ncol=4, fontsize=8)
    for a in ax:
        a.grid(alpha=0.3)
    fig.suptitle("The 8-setup sweep (the paper's Fig. 4 stages): static friction, then the coin slides toward −x")
    fig.tight_layout()
    atomic_write(png, lambda p: fig.savefig(p, dpi=100, format="png"), suffix=".png")
    plt.close(fig)
    return png


#: the metrics of the error-against-run-time plot's y axis, all in % of the coin's travel
X_MAE, TRAVEL, BOUND = "x(t) MAE", "travel error", "travel error bound"
#: how far meshes refined beyond the reference's ladder move the travel: the reference's error is
#: likely at least this (drawn ▲ where BOUND, the ladder's own bound, is ▼)
GAP = "travel change beyond the ladder"
GROUP_COLOURS = {"FEM ladder": "C0", "FEM benchmark": "C1", "contact convergence": "C2", "surrogate": "C3",
                 "surrogate on the ladder": "C4"}


def _finite_pos(v) -> bool:
    return v is not None and math.isfinite(v) and v > 0


def plot_error_time(points: list[dict], control: list[dict], png: Path) -> Path:
    """The figure of :func:`draw_error_time` written to ``png``."""
    fig = draw_error_time(points, control)
    atomic_write(png, lambda p: fig.savefig(p, dpi=100, format="png"), suffix=".png")
    plt.close(fig)
    return png


def draw_error_time(points: list[dict], control: list[dict]):
    """Left: wall time of a 1 s simulation against error in % of travel (``points`` of
    :func:`sections_error_time.error_time_points`); right: the control episodes (``control``).
    A point without a finite positive error is never drawn as one: diverged models sit on the top
    edge with the word, references with error 0 on the bottom edge, inputs not run in grey text."""
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(13, 6.4), gridspec_kw={"width_ratios": [1.35, 1]})
    edge = blended_transform_factory(ax.transData, ax.transAxes)
    walls = [p["wall_s"] for p in points if _finite_pos(p["wall_s"])]
    failed_rungs = labelled_top = 0
    for p in points:
        colour = GROUP_COLOURS.get(p["group"], "k")
        wall, err = p["wall_s"], p["error_pct"]
        if p["group"] == "paper":
            ax.axvline(wall, color="0.3", ls="--", lw=1)
            ax.text(wall, 0.5, f" {p['label']}: 1 s in {wall:g} s, error not reported", rotation=90, fontsize=7,
                    va="center", ha="right", transform=edge, color="0.3")
            continue
        if p["status"] == "not run" or not _finite_pos(wall):
            continue
        if p["status"].startswith("diverged") or (err is None and not p["status"].startswith("ref")):
            ax.plot([wall], [0.97], marker="^", color=colour, ms=9, transform=edge, clip_on=False)
            if p["group"] == "FEM ladder":    # many rungs: one note below, their rows in the CSV and table
                failed_rungs += 1
            else:
                ax.text(wall, 0.93 - 0.04 * (labelled_top % 3), f"{p['label']}: {p['status']}", transform=edge,
                        fontsize=7, ha="center", va="top", color=colour)
                labelled_top += 1
            continue
        if not _finite_pos(err):                   # a reference: error 0 by definition
            ax.plot([wall], [0.03], marker="*", color=colour, ms=11, transform=edge, clip_on=False)
            ax.text(wall, 0.06, f"{p['label']} (reference)", transform=edge, fontsize=7, ha="center", color=colour)
            continue
        marker, face = {BOUND: ("v", colour), GAP: ("^", colour)}.get(
            p["metric"], ("o", colour if p["metric"] == X_MAE else "none"))
        ax.plot([wall], [err], marker=marker, mfc=face, mec=colour, color=colour, ms=7, ls="none")
        if p["group"] != "FEM ladder":
            label = f"{p['label']}: refined beyond" if p["metric"] == GAP else p["label"]
            ax.annotate(label, (wall, err), textcoords="offset points", fontsize=7, color=colour,
                        xytext=(5, -10) if p["metric"] == BOUND else (5, 3))
    if failed_rungs:
        ax.text(0.99, 0.86, f"▲ on the top edge: {failed_rungs} FEM ladder rung(s) without an error (failed or "
                "not converged; see the table)", transform=ax.transAxes, fontsize=7, ha="right",
                color=GROUP_COLOURS.get("FEM ladder", "k"))
    ax.set_xscale("log")
    ax.set_yscale("log")
    errs = [p["error_pct"] for p in points if _finite_pos(p["error_pct"])]
    lo_x, hi_x = min(walls + [1e-3]), max(walls + [ABAQUS_S_LINE])
    ax.set_xlim(lo_x / 3, hi_x * 3)
    ax.set_ylim(min(errs + [0.1]) / 3, max(errs + [10.0]) * 10)
    ax.set_xlabel("wall time of a 1 s simulation [s]")
    ax.set_ylabel("error [% of the coin's travel]")
    ax.set_title("FEM levels and surrogates (coin_pull C3; surrogates: mean of the 6 sets)", fontsize=9)
    ax.grid(alpha=0.3, which="both")
    handles = [Line2D([], [], color=c, marker="o", ls="none", label=g) for g, c in GROUP_COLOURS.items()
               if any(p["group"] == g and p["status"] != "not run" for p in points)]
    handles += [Line2D([], [], color="k", marker="o", ls="none", label="x(t) MAE (filled)"),
                Line2D([], [], color="k", marker="o", mfc="none", ls="none", label="travel error (open)"),
                Line2D([], [], color="k", marker="v", ls="none", label="the reference's error bound")]
    if any(p["metric"] == GAP for p in points):
        handles.append(Line2D([], [], color="k", marker="^", ls="none",
                              label="refined beyond the reference's ladder: its error at least"))
    ax.legend(handles=handles, fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=4)
    _not_run_note(ax, [p for p in points if p["status"] == "not run"], lambda p: p["group"])

    policies = list(dict.fromkeys(c["policy"] for c in control if c["status"] != "not run"))
    noises = sorted({c["noise_std_m"] for c in control if c["status"] != "not run" and c["noise_std_m"] is not None})
    markers = dict(zip(noises, "osD^vP*X"))
    hidden = []
    for c in control:
        if c["status"] == "not run":
            continue
        wall, err = c["episode_wall_s_median"], c["final_error_pct_median"]
        if not (_finite_pos(wall) and _finite_pos(err)):
            hidden.append(f"{c['policy']} {c['plant']} {c['noise_std_m']:g} m")
            continue
        fem = c["plant"].startswith("fem:")
        bx.plot([wall], [err], ls="none", marker=markers.get(c["noise_std_m"], "o"), ms=8 if fem else 6,
                color=f"C{policies.index(c['policy']) % 10}", mec="k" if fem else None)
    bx.set_xscale("log")
    bx.set_yscale("log")
    bx.set_xlabel("wall time of one episode, median [s]")
    bx.set_ylabel("final |x − x^T|, median [% of the move]")
    bx.set_title("Control (another error: the closed loop's, not a simulation's)", fontsize=9)
    bx.grid(alpha=0.3, which="both")
    handles = [Line2D([], [], color=f"C{i % 10}", marker="o", ls="none", label=p) for i, p in enumerate(policies)]
    handles += [Line2D([], [], color="0.4", marker=m, ls="none", label=f"noise {n:g} m") for n, m in markers.items()]
    if any(c["plant"].startswith("fem:") for c in control if c["status"] != "not run"):
        handles.append(Line2D([], [], color="0.4", marker="o", mec="k", ms=8, ls="none", label="FEM plant"))
    if handles:
        bx.legend(handles=handles, fontsize=7, loc="best")
    notes = [c for c in control if c["status"] == "not run"]
    _not_run_note(bx, notes, lambda c: "control", extra=[f"not drawn (no finite error or time): {h}" for h in hidden])
    fig.tight_layout()
    return fig



def _not_run_note(ax, rows, what, extra=()) -> None:
    lines = [f"not run: {what(r)} — {r['make']}" for r in rows] + list(extra)
    if lines:
        ax.text(0.02, 0.02, "\n".join(lines), transform=ax.transAxes, fontsize=7, color="0.35", va="bottom",
                bbox=dict(facecolor="white", edgecolor="0.8", alpha=0.9))


#: the band of the control figure: these percentiles across the episodes, the line their middle
BAND_PERCENTILES = (10, 50, 90)


def plot_bands(panels: dict, png: Path, target_mm: float | None = None, tolerance_mm: float | None = None) -> Path:
    """Fig. 6 of the paper, with percentiles: a grid of plants (rows) × noise levels (columns), per
    policy the coin's x over the iterations, median line and 10–90 % band across the episodes.
    ``panels``: {(plant, noise): {policy: {"p10", "p50", "p90": arrays in mm, "episodes": n}}}."""
    plants = list(dict.fromkeys(p for p, _ in panels))
    noises = sorted({n for _, n in panels})
    policies = list(dict.fromkeys(pol for by in panels.values() for pol in by))
    fig, axes = plt.subplots(len(plants), len(noises), figsize=(4.2 * len(noises), 3.2 * len(plants)),
                             squeeze=False, sharex=True, sharey=True)
    lo, mid, hi = (f"p{q}" for q in BAND_PERCENTILES)
    for i, plant in enumerate(plants):
        for j, noise in enumerate(noises):
            ax = axes[i, j]
            for policy, b in panels.get((plant, noise), {}).items():
                colour = f"C{policies.index(policy) % 10}"
                t = np.arange(len(b[mid]))
                ax.plot(t, b[mid], color=colour, lw=1.3, label=f"{policy} ({b['episodes']} ep.)")
                ax.fill_between(t, b[lo], b[hi], color=colour, alpha=0.2, lw=0)
            if target_mm is not None:
                ax.axhline(target_mm, color="k", lw=0.8, ls="--")
                if tolerance_mm:
                    ax.axhspan(target_mm - tolerance_mm, target_mm + tolerance_mm, color="0.85", zorder=0)
            ax.set_xscale("symlog", linthresh=10)
            ax.grid(alpha=0.3)
            ax.set_title(f"{plant}, noise {noise:g} m", fontsize=9)
            if j == 0:
                ax.set_ylabel("coin x [mm]")
            if i == len(plants) - 1:
                ax.set_xlabel("iteration (Δt = 1 ms; symlog)")
            if (plant, noise) in panels:
                ax.legend(fontsize=7, loc="upper right")
    fig.suptitle(f"Coin position per policy: median and {BAND_PERCENTILES[0]}–{BAND_PERCENTILES[2]} % band across "
                 "the episodes (finished episodes held at their last position); dashed: the target", fontsize=9)
    fig.tight_layout()
    atomic_write(png, lambda p: fig.savefig(p, dpi=100, format="png"), suffix=".png")
    plt.close(fig)
    return png
