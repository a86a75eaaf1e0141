"""Held-out protocols and held-out coins: train on ramps + excitation, test on what was not seen.

The paper's sets (:mod:`deapull.surrogate.experiments`) test ramps only. A controller plays
holds, decreases and turns, so here every model kind is trained once on the ramps and the
*training protocols* (default: ramp–hold–ramp and two seeded random inputs) of the *training
coins*, early-stopped on the same protocols of the *validation coins*, and rolled out
(recursively, over the whole run, from the FEM's first state under the FEM's voltages) on

* the ramps of every coin that was neither trained nor validated on (held-out coins),
* the held-out protocols (default: release, triangle, random input 3) of every coin
  with excitation data (held-out protocols; on the test coins also held-out coins),
* the training protocols of the test coins (held-out coins),

with the error of x in % of the run's travel (the largest |x| of the FEM run), as
:func:`deapull.surrogate.evaluate.evaluate` computes it. Each physics model simulates the
run's coin, φ from the coin's ramp run (for the paper's law its V^T: a release never moves
the coin toward −x, so has none of its own).

Runs: ramps ``<data>/<coin>.nc``, the rest ``<excitation>/<coin>_<protocol>.nc`` (``deapull
sweep --protocols excitation``). Resumable: a model folder ``<out>/<kind>/`` that holds a
trained model is loaded instead of trained again, and an evaluation ``<out>/<kind>/eval/
<run>.json`` newer than its model and its data files is reused. Written: ``protocols.csv`` (one row per model and
run), ``protocols.md`` (the summary by protocol and the per-run table), ``protocols.json`` and
``protocols.png`` (x(t) on the test coin, FEM and models).
"""
from __future__ import annotations

import json
import logging
import math
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from deapull.errors import InputError
from deapull.io import markdown_of, markdown_table, table_record, write_csv, write_json, write_text
from deapull.surrogate import card, ensemble, store
from deapull.surrogate.data import DatasetError, SetupData, load_setup
from deapull.surrogate.evaluate import evaluate
from deapull.surrogate.models import KINDS
from deapull.surrogate.rollout import OutOfRangeWarning
from deapull.surrogate.train import TrainConfig, train

log = logging.getLogger(__name__)

#: the default model kinds, the new f first
DEFAULT_KINDS = ("f-memory", "f-coulomb", "f", "nn", "lstm")
#: protocol columns of the summary: column -> protocols pooled in it
COLUMNS = {"ramp": ("ramp",), "rhr": ("rhr",), "release": ("release",), "triangle": ("triangle",),
           "random": ("random1", "random2", "random3")}
#: the excitation protocols (``deapull sweep --protocols excitation``)
EXCITATION_PROTOCOLS = tuple(p for column, protocols in COLUMNS.items() if column != "ramp" for p in protocols)
CSV_COLUMNS = ("model", "run", "coin", "protocol", "role", "x_error_pct_travel", "mae_x_m", "max_abs_x_error_m",
               "final_x_error_m", "travel_m", "mae_Fx_N", "mae_Fy_N", "diverged", "steps", "rollout_ms",
               "out_of_range_warnings", "band_coverage", "band_half_width_pct_travel")


@dataclass(frozen=True)
class Design:
    """Which coins and protocols train, validate and test.

    Attributes
    ----------
    train_coins, val_coins, test_coins : tuple of str
        Setups (``C1`` ...). The validation coins' training protocols decide early stopping.
    train_protocols : tuple of str
        ``ramp`` and excitation protocols (``rhr``, ``random1`` ...) trained on.
    test_protocols : tuple of str
        Held-out excitation protocols, evaluated on every coin that has them.
    ramp_coins : tuple of str
        Coins whose ramps are evaluated (default: every ramp in the data folder not trained
        or validated on).
    """

    train_coins: tuple = ("C1",)
    val_coins: tuple = ("C3",)
    test_coins: tuple = ("C5", "C7")
    train_protocols: tuple = ("ramp", "rhr", "random1", "random2")
    test_protocols: tuple = ("release", "triangle", "random3")
    ramp_coins: tuple = ()

    def check(self) -> None:
        seen = set(self.train_coins) & (set(self.val_coins) | set(self.test_coins))
        if seen or set(self.val_coins) & set(self.test_coins):
            raise InputError(f"a coin is in two roles: train {self.train_coins}, val {self.val_coins}, "
                             f"test {self.test_coins}")
        if set(self.train_protocols) & set(self.test_protocols):
            raise InputError(f"protocols {sorted(set(self.train_protocols) & set(self.test_protocols))} are both "
                             "trained on and held out")
        if not self.train_coins or not self.val_coins or not self.train_protocols:
            raise InputError("need at least one training coin, one validation coin and one training protocol")


def run_name(coin: str, protocol: str) -> str:
    return coin if protocol == "ramp" else f"{coin}_{protocol}"


def run_path(data_dir: Path, excitation_dir: Path, coin: str, protocol: str) -> Path:
    return data_dir / f"{coin}.nc" if protocol == "ramp" else excitation_dir / f"{coin}_{protocol}.nc"


def cases(design: Design, data_dir: Path, excitation_dir: Path) -> list[tuple[str, str, str]]:
    """The evaluation runs as (coin, protocol, role), role ``held-out coin``, ``held-out
    protocol`` or ``held-out coin and protocol``; runs whose file is missing are left out."""
    trained = set(design.train_coins) | set(design.val_coins)
    ramp_coins = design.ramp_coins or tuple(sorted((p.stem for p in data_dir.glob("C*.nc") if "_" not in p.stem),
                                                   key=lambda n: (len(n), n)))
    out = [(c, "ramp", "held-out coin") for c in ramp_coins if c not in trained]
    coins = [*design.train_coins, *design.val_coins, *design.test_coins]
    for coin in coins:
        for protocol in (*design.train_protocols, *design.test_protocols):
            if protocol == "ramp":
                continue
            held_coin, held_protocol = coin in design.test_coins, protocol in design.test_protocols
            if not (held_coin or held_protocol):
                continue
            if not run_path(data_dir, excitation_dir, coin, protocol).is_file():
                log.warning("no run %s: left out", run_path(data_dir, excitation_dir, coin, protocol))
                continue
            role = ("held-out coin and protocol" if held_coin and held_protocol
                    else "held-out coin" if held_coin else "held-out protocol")
            out.append((coin, protocol, role))
    return out


def _load(data_dir, excitation_dir, coin, protocol) -> SetupData:
    return load_setup(run_path(data_dir, excitation_dir, coin, protocol))


def coin_phi(kind: str, ramp: SetupData):
    """φ of a coin for ``kind``, from the coin's ramp run (None for the black boxes)."""
    cls = KINDS[kind]
    return cls.phi_of(ramp) if cls.physics else None


def _runs(coins, protocols, data_dir: Path, excitation_dir: Path, role: str) -> list[SetupData]:
    """The runs of ``coins`` × ``protocols``; a missing excitation run is left out with a warning
    (a missing ramp raises)."""
    runs = []
    for c in coins:
        for p in protocols:
            path = run_path(data_dir, excitation_dir, c, p)
            if p != "ramp" and not path.is_file():
                log.warning("%s run %s is missing: %s without it", role, path, role)
                continue
            runs.append(_load(data_dir, excitation_dir, c, p))
    return runs


def train_or_load(kind: str, base: TrainConfig, design: Design, data_dir: Path, excitation_dir: Path, out: Path):
    """The model of ``kind`` under ``out/<kind>``: loaded when trained before, else trained."""
    folder = out / kind
    if (folder / "model.json").is_file() and (folder / "model.pt").is_file():
        model, meta = store.load(folder)
        trained = meta.get("training", {}).get("design") or {}
        if all(trained.get(k) == list(getattr(design, k)) for k in ("train_coins", "val_coins", "train_protocols")):
            log.info("%s: reusing the model in %s", kind, folder)
            return model, meta.get("training", {})
        log.info("%s: the model in %s was trained on another design: training again", kind, folder)
    train_runs = _runs(design.train_coins, design.train_protocols, data_dir, excitation_dir, "training")
    val_runs = _runs(design.val_coins, design.train_protocols, data_dir, excitation_dir, "validation")
    ramps = {c: _load(data_dir, excitation_dir, c, "ramp") for c in (*design.train_coins, *design.val_coins)}
    phis = {}
    for c in ramps:
        phi = coin_phi(kind, ramps[c])
        if phi is not None:
            phis.update({run_name(c, p): phi for p in design.train_protocols})
    result = train(replace(base, kind=kind), train_runs, val_runs, phis=phis)
    store.save(result.model, folder, {**result.summary(), "design": design.__dict__}, result.history)
    if len(result.members) >= 2:     # the restarts' ensemble and its band's scales
        names, k, k_fallen = _band_scales(kind, result.members, design, data_dir, excitation_dir)
        ensemble.save(result, folder, k, k_fallen, names)
    return result.model, result.summary()


def calibration_runs(design: Design, data_dir: Path, excitation_dir: Path) -> list[tuple[str, str]]:
    """The runs an ensemble's band is calibrated on, as (coin, protocol): every run of the
    validation coins, the ramp and each excitation protocol present. The band then carries the
    error of the protocols the models did not train on (the voltage falling) as the validation
    coin shows it; no test coin's run enters."""
    return [(c, p) for c in design.val_coins for p in ("ramp", *EXCITATION_PROTOCOLS)
            if run_path(data_dir, excitation_dir, c, p).is_file()]


def _band_scales(kind: str, members, design: Design, data_dir: Path, excitation_dir: Path):
    """(names of :func:`calibration_runs`, k, k_fallen) of the ensemble ``members``: k on the runs'
    points before the voltage first falls, k_fallen on those after (None when no run's voltage falls)."""
    data, phis = [], {}
    for c, p in calibration_runs(design, data_dir, excitation_dir):
        data.append(_load(data_dir, excitation_dir, c, p))
        phi = coin_phi(kind, _load(data_dir, excitation_dir, c, "ramp"))
        phis[data[-1].name] = phi if phi is not None else members[0].phi_of(data[-1])
    k = ensemble.calibrate(members, data, phis, where=lambda d: ~ensemble.fallen(d))
    k_fallen = ensemble.calibrate(members, data, phis, where=ensemble.fallen)
    k_fallen = None if math.isnan(k_fallen) else k_fallen
    log.info("%s: band calibrated on %s (k = %.3g, where the voltage has fallen %s)", kind,
             ", ".join(d.name for d in data), k, "k" if k_fallen is None else f"{k_fallen:.3g}")
    return [d.name for d in data], k, k_fallen


def calibrate_band(kind: str, design: Design, data_dir: Path, excitation_dir: Path, out: Path):
    """The ensemble (members, k, k_fallen) of ``out/<kind>``, its scales (:func:`_band_scales`)
    calibrated again only when :func:`calibration_runs` changed since; None without an ensemble."""
    folder = out / kind
    if not (folder / ensemble.CALIBRATION).is_file():
        return None
    members, k = ensemble.load(folder)
    meta = ensemble.calibration(folder)
    names = [run_name(c, p) for c, p in calibration_runs(design, data_dir, excitation_dir)]
    if meta["calibrated_on"] != names or "k_fallen" not in meta:
        names, k, k_fallen = _band_scales(kind, members, design, data_dir, excitation_dir)
        ensemble.write_calibration(folder, k, names, k_fallen)
        return members, k, k_fallen
    return members, k, meta["k_fallen"]


def evaluate_case(model, kind: str, coin: str, protocol: str, role: str, data_dir: Path, excitation_dir: Path,
                  out: Path, band=None) -> dict:
    """The row of one model on one run (reused from ``<out>/<kind>/eval/<run>.json`` when newer
    than the model); ``band``: the model's ensemble (members, k, k_fallen), whose coverage of the run the row
    gives."""
    name = run_name(coin, protocol)
    cache = out / kind / "eval" / f"{name}.json"
    inputs = [out / kind / "model.pt", run_path(data_dir, excitation_dir, coin, protocol),
              run_path(data_dir, excitation_dir, coin, "ramp"), *([out / kind / ensemble.CALIBRATION] if band else [])]
    if cache.is_file() and all(f.is_file() and cache.stat().st_mtime >= f.stat().st_mtime for f in inputs):
        return json.loads(cache.read_text())
    data = _load(data_dir, excitation_dir, coin, protocol)
    phi = coin_phi(kind, _load(data_dir, excitation_dir, coin, "ramp"))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", OutOfRangeWarning)
        ev = evaluate(model, data, phi=phi)
    coverage = width = None
    if band is not None:
        members, k, k_fallen = band
        b = ensemble.band(members, k, data, phi if phi is not None else model.phi_of(data), k_fallen)
        coverage, width = b.coverage(data.x), 100 * b.half_width_share(data.x)
    row = {**{k: ev.metrics.get(k) for k in CSV_COLUMNS}, "model": kind, "run": name, "coin": coin,
           "protocol": protocol, "role": role, "out_of_range_warnings": len(caught), "band_coverage": coverage,
           "band_half_width_pct_travel": width,
           "t": ev.t.tolist(), "x_fem": ev.x_fem.tolist(), "x_model": ev.x_model.tolist()}
    write_json(cache, row)
    return row


def run(data_dir: str | Path, out_dir: str | Path, base: TrainConfig, excitation_dir: str | Path | None = None,
        kinds=DEFAULT_KINDS, design: Design = Design(), restarts: dict | None = None) -> list[dict]:
    """Train (or reuse) every kind, evaluate it on every held-out run, write the tables.

    Returns
    -------
    list of dict
        One row per (model, run), the keys of :data:`CSV_COLUMNS`.
    """
    design.check()
    for kind in kinds:
        if kind not in KINDS:
            raise InputError(f"model {kind!r} is not a model; choose from {', '.join(KINDS)}")
    data_dir = Path(data_dir)
    excitation_dir = Path(excitation_dir) if excitation_dir else data_dir / "excitation"
    for d in (data_dir, excitation_dir):
        if not d.is_dir():
            raise DatasetError(f"{d}: no such data folder")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    todo = cases(design, data_dir, excitation_dir)
    rows = []
    for kind in kinds:
        cfg = replace(base, restarts=(restarts or {}).get(kind, base.restarts))   # restarts: per kind, or base's
        model, _ = train_or_load(kind, cfg, design, data_dir, excitation_dir, out)
        # a model trained with restarts keeps its ensemble: the band of every run
        band = calibrate_band(kind, design, data_dir, excitation_dir, out)
        for coin, protocol, role in todo:
            rows.append(evaluate_case(model, kind, coin, protocol, role, data_dir, excitation_dir, out, band))
    summary = summarise(rows, kinds)
    text = format_markdown(summary, rows, kinds, design)
    write_text(out / "protocols.md", text + "\n")
    write_csv(out / "protocols.csv", rows, CSV_COLUMNS)
    write_json(out / "protocols.json", {"rows": [{k: r.get(k) for k in CSV_COLUMNS} for r in rows],
                                        "summary": summary, "tables": tables(summary, rows, kinds),
                                        "design": design.__dict__, "kinds": list(kinds),
                                        "data": str(data_dir), "excitation": str(excitation_dir),
                                        "config": {k: v for k, v in vars(base).items() if k != "kind"}}, indent=2)
    plot(rows, kinds, design, out / "protocols.png")
    return rows


def summarise(rows: list[dict], kinds) -> list[dict]:
    """Per model: the mean and largest x error (% of travel) over the runs of each protocol
    column (:data:`COLUMNS`); a diverged rollout counts as infinite in the largest and is
    left out of the mean (and counted)."""
    out = []
    for kind in kinds:
        rec = {"model": kind, "label": KINDS[kind].label}
        for col, protocols in COLUMNS.items():
            mine = [r for r in rows if r["model"] == kind and r["protocol"] in protocols]
            ok = [r["x_error_pct_travel"] for r in mine if not r["diverged"]]
            rec[f"{col}_mean"] = float(np.mean(ok)) if ok else None
            rec[f"{col}_max"] = (math.inf if any(r["diverged"] for r in mine) else max(ok)) if mine else None
            rec[f"{col}_n"] = len(mine)
            rec[f"{col}_diverged"] = sum(bool(r["diverged"]) for r in mine)
        out.append(rec)
    return out


def _mean_max(rec: dict, col: str) -> str:
    m, x = rec.get(f"{col}_mean"), rec.get(f"{col}_max")
    if rec.get(f"{col}_n", 0) == 0:
        return "–"
    mean = "–" if m is None else f"{m:.2f}"
    top = "div." if x is not None and math.isinf(x) else ("–" if x is None else f"{x:.2f}")
    return f"{mean} ({top})"


def verdicts(summary: list[dict], kinds) -> list[str]:
    """How far the goal is: f ≤ 2 % on every held-out protocol column, ahead of NN and LSTM."""
    by = {r["model"]: r for r in summary}
    lines = []
    boxes = [k for k in kinds if not KINDS[k].physics]
    for kind in (k for k in kinds if KINDS[k].physics):
        rec = by[kind]
        cols = [c for c in COLUMNS if rec.get(f"{c}_n")]
        under = [c for c in cols if rec[f"{c}_mean"] is not None and rec[f"{c}_mean"] <= 2.0 and not rec[f"{c}_diverged"]]
        ahead = [c for c in cols if rec[f"{c}_mean"] is not None and all(
            by[b][f"{c}_mean"] is None or by[b][f"{c}_diverged"] or rec[f"{c}_mean"] < by[b][f"{c}_mean"]
            for b in boxes)]
        lines.append(f"{KINDS[kind].label}: mean <= 2 % on {len(under)}/{len(cols)} protocols"
                     f"{' (' + ', '.join(c for c in cols if c not in under) + ' above)' if len(under) < len(cols) else ''}; "
                     f"ahead of {' and '.join(KINDS[b].label for b in boxes) or 'no baseline'} on {len(ahead)}/{len(cols)}")
    return lines


def format_text(summary: list[dict], kinds) -> str:
    """The summary as plain text: one line per model, mean (largest) x error per protocol."""
    cols = [c for c in COLUMNS if any(r.get(f"{c}_n") for r in summary)]
    head = ["x error [% of travel], mean (max)"] + cols
    lines = [head] + [[r["label"]] + [_mean_max(r, c) for c in cols] for r in summary]
    widths = [max(len(line[i]) for line in lines) for i in range(len(head))]
    table = "\n".join("  ".join(c.ljust(w) if j == 0 else c.rjust(w) for j, (c, w) in enumerate(zip(line, widths)))
                      for line in lines)
    counts = "runs per column: " + ", ".join(f"{c} {summary[0][f'{c}_n']}" for c in cols)
    return table + "\n" + counts + "\n" + "\n".join(verdicts(summary, kinds))


def tables(summary: list[dict], rows: list[dict], kinds) -> list[dict]:
    """The summary by protocol and the per-run table as data (:func:`deapull.io.table_record`)."""
    cols = [c for c in COLUMNS if any(r.get(f"{c}_n") for r in summary)]
    table = table_record([{"label": r["label"], **{c: _mean_max(r, c) for c in cols}} for r in summary],
                         [("model", "label", "s")] + [(c, c, "s") for c in cols])
    runs = sorted({(r["run"], r["coin"], r["protocol"], r["role"]) for r in rows},
                  key=lambda k: (list(COLUMNS).index(next(c for c, ps in COLUMNS.items() if k[2] in ps)), k[0]))
    by = {(r["model"], r["run"]): r for r in rows}
    per_run = []
    for name, coin, protocol, role in runs:
        rec = {"run": name, "role": role, "travel": by[(kinds[0], name)]["travel_m"] * 1e3}
        for k in kinds:
            r = by[(k, name)]
            rec[k] = "div." if r["diverged"] else f"{r['x_error_pct_travel']:.2f}"
        per_run.append(rec)
    per_table = table_record(per_run, [("run", "run", "s"), ("held out", "role", "s"), ("travel mm", "travel", ".3f")]
                             + [(KINDS[k].label, k, "s") for k in kinds])
    return [table, per_table]


def format_markdown(summary: list[dict], rows: list[dict], kinds, design: Design) -> str:
    table, per_table = (markdown_of(t) for t in tables(summary, rows, kinds))
    return (f"# Held-out protocols and coins\n\nTrained on coins {', '.join(design.train_coins)} with protocols "
            f"{', '.join(design.train_protocols)}; early-stopped on {', '.join(design.val_coins)}; test coins "
            f"{', '.join(design.test_coins)}; held-out protocols {', '.join(design.test_protocols)}.\n\n"
            "x error of the recursive rollout over the whole run, % of the run's travel: mean (largest) over the "
            "runs of each protocol (random: random1–3 pooled).\n\n" + table + "\n\n"
            + "\n".join(f"* {v}" for v in verdicts(summary, kinds)) + "\n\n## Per run\n\n" + per_table)


def plot(rows: list[dict], kinds, design: Design, path: Path) -> Path | None:
    """x(t) of the FEM and of each model, one run per protocol: the first test coin's, else the
    first coin's that has it."""
    import matplotlib  # lazy: matplotlib (~0.5 s) loads only when a figure is drawn
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    coin = design.test_coins[0] if design.test_coins else design.train_coins[0]
    mine = [r for r in rows if r["model"] == kinds[0]]
    names = []
    for protocol in dict.fromkeys(r["protocol"] for r in mine):
        runs = [r for r in mine if r["protocol"] == protocol]
        names.append(next((r for r in runs if r["coin"] == coin), runs[0])["run"])
    if not names:
        return None
    by = {(r["model"], r["run"]): r for r in rows}
    cols = min(3, len(names))
    nrows = -(-len(names) // cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(4.2 * cols, 3.2 * nrows), squeeze=False)
    for ax, name in zip(axes.flat, names):
        r0 = by[(kinds[0], name)]
        ax.plot(r0["t"], np.array(r0["x_fem"]) * 1e3, "k-", lw=2.5, alpha=0.4, label="FEM")
        for j, k in enumerate(kinds):
            r = by[(k, name)]
            ax.plot(r["t"], np.array(r["x_model"]) * 1e3, color=f"C{j}", lw=1,
                    label=KINDS[k].label + (" (diverged)" if r["diverged"] else ""))
        lim = 1e3 * r0["travel_m"]
        ax.set_ylim(-1.5 * lim, 1.5 * lim)
        ax.set_title(f"{name} ({r0['role']})", fontsize=9)
        ax.set_xlabel("t (s)")
        ax.set_ylabel("x (mm)")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=6)
    for ax in list(axes.flat)[len(names):]:
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


#: the friction pairs of the design (setups that share μ_b and μ_t and differ in the coin's density)
PAIRS = (("C1", "C2"), ("C3", "C4"), ("C5", "C6"), ("C7", "C8"))


def pair_designs(coins=tuple(c for pair in PAIRS for c in pair), test_protocols=()) -> list[tuple[tuple, Design]]:
    """Leave one friction pair out at a time: early-stop on the next pair's first coin and train on
    the ramps of the two other pairs, test on the held-out pair's ramps and its runs of
    ``test_protocols``. The validation coin's sibling sits out too: its run then shows a friction
    the model has not seen, as the held-out pair does, and the ensemble's band is calibrated on it
    (docs/surrogate.md, "Held-out coins")."""
    out = []
    for j, held in enumerate(PAIRS):
        beside = PAIRS[(j + 1) % len(PAIRS)]
        val = beside[0]
        train = tuple(c for c in coins if c not in held and c not in beside)
        out.append((held, Design(train_coins=train, val_coins=(val,), test_coins=held, train_protocols=("ramp",),
                                 test_protocols=tuple(test_protocols), ramp_coins=held)))
    return out


def run_pairs(data_dir: str | Path, out_dir: str | Path, base: TrainConfig, kinds=("f-coulomb",),
              restarts: dict | None = None, excitation_dir: str | Path | None = None) -> list[dict]:
    """:func:`run` on each design of :func:`pair_designs` (into ``<out>/pair_<C>_<C>/``), tested also
    on the held-out pair's excitation runs in ``excitation_dir`` (held-out coin and protocol); writes
    ``pairs.csv`` and ``pairs.md`` (x error of each held-out run, % of travel, per kind) and returns
    the rows (with ``pair``).

    The models train on ramps only; the held-out pair's excitation runs test them on protocols and a
    coin they never saw.
    """
    out = Path(out_dir)
    excitation = Path(excitation_dir) if excitation_dir else None
    protocols = tuple(p for p in EXCITATION_PROTOCOLS if excitation is not None and any(excitation.glob(f"C*_{p}.nc")))
    designs = pair_designs(test_protocols=protocols)
    rows = []
    for held, design in designs:
        name = "pair_" + "_".join(held)
        for row in run(data_dir, out / name, base, excitation_dir=excitation or data_dir, kinds=kinds, design=design,
                       restarts=restarts):
            if row["coin"] in held:
                rows.append({**{k: row.get(k) for k in CSV_COLUMNS}, "pair": "/".join(held)})
    write_csv(out / "pairs.csv", rows, ("pair", *CSV_COLUMNS))
    write_text(out / "pairs.md", pairs_table(rows, kinds) + "\n")
    runs = list(dict.fromkeys((r["pair"], r["run"]) for r in rows))
    by = {(r["model"], r["run"]): r for r in rows}
    ramps = [load_setup(run_path(Path(data_dir), Path(data_dir), c, "ramp")) for pair in PAIRS for c in pair]
    write_json(out / "pairs.json", {
        "data": {"fidelity": sorted({card.fidelity_label(d.fidelity) for d in ramps}),
                 "fidelity_id": sorted({d.fidelity_id for d in ramps})},
        "kinds": list(kinds), "labels": {k: KINDS[k].label for k in kinds},
        "designs": {"/".join(h): {"train": list(d.train_coins), "val": list(d.val_coins)} for h, d in designs},
        "test_protocols": ["ramp", *protocols],
        "runs": [{"pair": p, "run": n, "protocol": by[(kinds[0], n)]["protocol"], "travel_m": by[(kinds[0], n)]["travel_m"],
                  **{k: None if by[(k, n)]["diverged"] else by[(k, n)]["x_error_pct_travel"] for k in kinds},
                  "band_coverage": {k: by[(k, n)]["band_coverage"] for k in kinds
                                    if by[(k, n)].get("band_coverage") is not None},
                  "band_half_width_pct_travel": {k: by[(k, n)]["band_half_width_pct_travel"] for k in kinds
                                                 if by[(k, n)].get("band_half_width_pct_travel") is not None}}
                 for p, n in runs], "band_level": ensemble.LEVEL}, indent=2)
    return rows


def pairs_table(rows: list[dict], kinds) -> str:
    """One line per held-out run: its pair, travel and each kind's x error (% of travel), then the
    largest per kind, on the ramps and on the excitation runs apart."""
    runs = list(dict.fromkeys((r["pair"], r["run"]) for r in rows))
    by = {(r["model"], r["run"]): r for r in rows}
    table = [{"pair": p, "run": n, "travel": 1e3 * by[(kinds[0], n)]["travel_m"],
              **{k: "div." if by[(k, n)]["diverged"] else f"{by[(k, n)]['x_error_pct_travel']:.2f}" for k in kinds}}
             for p, n in runs]
    lines = []
    for what, group in (("ramp", [n for _, n in runs if by[(kinds[0], n)]["protocol"] == "ramp"]),
                        ("excitation run", [n for _, n in runs if by[(kinds[0], n)]["protocol"] != "ramp"])):
        for k in kinds if group else ():
            worst = max(math.inf if by[(k, n)]["diverged"] else by[(k, n)]["x_error_pct_travel"] for n in group)
            shown = f"{worst:.2f} % of travel" if math.isfinite(worst) else "diverged"
            lines.append(f"* {KINDS[k].label}: largest x error on a held-out {what} {shown}")
            cover = [by[(k, n)]["band_coverage"] for n in group if by[(k, n)].get("band_coverage") is not None]
            width = [by[(k, n)].get("band_half_width_pct_travel") for n in group]
            width = "" if None in width else f", its half-width {np.mean(width):.1f} % of travel"
            if cover:
                lines.append(f"* {KINDS[k].label}: its {100 * ensemble.LEVEL:.0f} % band covers "
                             f"{100 * np.mean(cover):.1f} % of the held-out {what}s' points (lowest {100 * min(cover):.1f} %)"
                             + width)
    return (markdown_table(table, [("held-out pair", "pair", "s"), ("run", "run", "s"), ("travel mm", "travel", ".3f")]
                           + [(f"{KINDS[k].label} x error [%]", k, "s") for k in kinds])
            + "\n\n" + "\n".join(lines))
