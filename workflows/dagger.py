"""Dataset aggregation for the MPC's model (``deapull dagger``): f_a learns the FEM's closed
loop from the transitions the controller itself visits.

f_a is trained on the FEM's ramps. Under the MPC the FEM goes where no ramp goes: fast
pushes that stop, holds, voltages that come down. Round k:

1. run the MPC planning with f_a(k) on the FEM plant(s), the FEM stepped online; every
   episode is saved as a dataset of the FEM's contract (:meth:`FEMPlant.save`);
2. measure f_a(k) on those new closed-loop runs, which it has not trained on: the open-loop
   rollout of the coin under the episode's voltages (:func:`deapull.surrogate.evaluate.evaluate`:
   largest |x error|, mean |x error|, % of travel);
3. add the runs to the training set and train f_a(k + 1) on the ramps and every run so far
   (validated on the same ramp as f_a(0)).

It stops after ``rounds`` rounds, or earlier once the closed loop stops improving: a round
whose episodes settle no more often and overshoot no less (mean) than the best round so far.
Outputs in ``--out``: ``models/r<k>/`` (f_a(k)), ``runs/`` (every saved episode),
``control/r<k>/`` (the harness's outputs of each round), ``dagger.csv`` and ``dagger.md``
(one row per round: training runs and transitions, the model's error on the round's new
runs, reached / settled / overshoot / hold error of the closed loop).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from deapull.errors import InputError
from deapull.io import markdown_table, write_csv, write_text
from deapull.surrogate import store
from deapull.surrogate.data import load_setup, load_sweep
from deapull.surrogate.evaluate import evaluate
from deapull.surrogate.train import TrainConfig, train
from deapull.workflows import control

log = logging.getLogger(__name__)

COLUMNS = ("round", "train_runs", "train_transitions", "new_runs", "model_max_abs_x_error_mm",
           "model_mae_x_mm", "model_x_error_pct_travel", "reached", "settled", "overshoot_mm_mean",
           "hold_max_abs_error_mm_mean", "final_abs_error_mm_mean")


@dataclass
class DaggerConfig:
    """What ``deapull dagger`` runs (``deapull dagger --help``).

    ``control`` is the closed-loop experiment of each round (:class:`ControlConfig`, MPC on FEM
    plants); its ``mpc_model``, ``out``, ``save_fem_runs`` and ``run_tag`` are set per round.
    ``kind`` is f_a's model kind, retrained every round: None means the kind of ``model`` when
    one is given, else f-coulomb. A kind that cannot infer φ online (capability ``infer``) plans
    with the prior's median: it needs ``control.mpc_phi = "prior"``.
    """

    control: object
    data: Path
    train: list
    val: str
    out: Path
    rounds: int = 3
    epochs: int = 300
    kind: str | None = None
    model: Path | None = None
    seed: int = 0
    extra: list = field(default_factory=list)


def model_kind(config: DaggerConfig) -> str:
    """f_a's kind: ``config.kind``, else the given model's, else f-coulomb."""
    given = store.kind_of(config.model) if config.model is not None else None
    return config.kind or given or "f-coulomb"


def check(config: DaggerConfig) -> None:
    """Refuse bad settings before any training or FEM step."""
    from deapull.surrogate.models import registry
    kind = model_kind(config)
    cls = registry.KINDS.get(kind)
    if cls is None or "plan" not in cls.capabilities:
        allowed = ", ".join(k for k, c in registry.KINDS.items() if "plan" in c.capabilities)
        raise InputError(f"--model-kind {kind!r}: the MPC cannot plan with it; allowed: {allowed}")
    given = store.kind_of(config.model) if config.model is not None else None
    if given is not None and given != kind:
        raise InputError(f"--model-kind {kind!r} but --mpc-model {str(config.model)!r} is {given!r}: every round "
                         f"retrains the same kind")
    if "infer" not in cls.capabilities and config.control.mpc_phi == "infer":
        source = "--model-kind" if config.kind is not None else f"the kind of --mpc-model {str(config.model)!r}"
        raise InputError(f"f_a's kind {kind!r} ({source}) cannot infer the coin online: plan with the prior's "
                         f"median (a --preset with control.mpc_phi = 'prior', e.g. fem)")
    if int(config.rounds) != config.rounds or config.rounds < 1:
        raise InputError(f"--rounds {config.rounds!r}: must be an integer >= 1")
    if int(config.epochs) != config.epochs or config.epochs < 1:
        raise InputError(f"--epochs {config.epochs!r}: must be an integer >= 1")
    if any(p.kind != "fem" for p in config.control.plants):
        raise InputError("--plant: dataset aggregation runs on FEM plants only (fem:C3, ...)")
    if config.control.policies != ["mpc"]:
        raise InputError("dataset aggregation trains the MPC's model: the policy is mpc")
    for name in [*config.train, config.val]:
        if not (Path(config.data) / f"{name}.nc").is_file():
            raise InputError(f"--data {str(config.data)!r}: {name}.nc not found (the ramps f_a starts from)")


def train_model(ramps: dict, train_names: list, val: str, settings: TrainConfig, runs: list[Path], out: Path):
    """f_a on the ramps ``train_names`` and the aggregated ``runs`` (validated on the ramp ``val``);
    saved in ``out``. ``ramps``: the ramps by name, read once per run."""
    train_sets = [ramps[n] for n in train_names] + [load_setup(p) for p in runs]
    result = train(settings, train_sets, ramps[val])
    store.save(result.model, out, result.summary(), result.history)
    return result.model, sum(d.n_steps - 1 for d in train_sets), len(train_sets)


def model_error(model, runs: list[Path]) -> dict:
    """f_a's open-loop rollout on each closed-loop run it has not trained on, against the FEM:
    the largest |x error| and the mean |x error| (mm) and the error in % of travel (means over
    the runs)."""
    if not runs:
        return {"model_max_abs_x_error_mm": math.nan, "model_mae_x_mm": math.nan,
                "model_x_error_pct_travel": math.nan}
    rows = [evaluate(model, load_setup(p)).metrics for p in runs]
    return {"model_max_abs_x_error_mm": 1e3 * float(np.mean([r["max_abs_x_error_m"] for r in rows])),
            "model_mae_x_mm": 1e3 * float(np.mean([r["mae_x_m"] for r in rows])),
            "model_x_error_pct_travel": float(np.mean([r["x_error_pct_travel"] for r in rows]))}


def closed_loop(rows: list[dict]) -> dict:
    """What the round's episodes achieved (on the true state)."""
    reached = [r for r in rows if r["reached"]]
    return {"reached": f"{len(reached)}/{len(rows)}", "settled": f"{sum(r['settled'] for r in rows)}/{len(rows)}",
            "settled_n": sum(r["settled"] for r in rows),
            "overshoot_mm_mean": 1e3 * float(np.mean([r["overshoot_m"] for r in rows])),
            "hold_max_abs_error_mm_mean": (1e3 * float(np.mean([r["hold_max_abs_error_m"] for r in reached]))
                                           if reached else math.nan),
            "final_abs_error_mm_mean": 1e3 * float(np.mean([r["final_abs_error_m"] for r in rows]))}


def improved(result: dict, best: dict | None) -> bool:
    """A round improves on the best so far when more episodes settle, or as many with less
    overshoot."""
    if best is None:
        return True
    return (result["settled_n"], -result["overshoot_mm_mean"]) > (best["settled_n"], -best["overshoot_mm_mean"])


def run(config: DaggerConfig) -> list[dict]:
    """The rounds (module docstring); returns one row per round and writes the tables."""
    check(config)
    control.check(replace(config.control, mpc_model=str(config.model or "")),
                  mpc_model_trained=config.model is not None)
    out = Path(config.out)
    runs_dir = out / "runs"
    runs_dir.mkdir(parents=True, exist_ok=True)
    aggregated: list[Path] = list(config.extra)
    training = TrainConfig(kind=model_kind(config), epochs=config.epochs, seed=config.seed)
    trains = config.model is None or config.rounds > 1
    ramps = load_sweep(config.data, list(dict.fromkeys([*config.train, config.val]))) if trains else {}
    if config.model is not None:
        model, _ = store.load(config.model)
        model_dir = Path(config.model)
        n_transitions, n_runs = math.nan, len(config.train)
    else:
        model_dir = out / "models" / "r0"
        model, n_transitions, n_runs = train_model(ramps, config.train, config.val, training, aggregated, model_dir)
    rows, best = [], None
    for k in range(config.rounds):
        log.info("dagger round %d: MPC on %s with f_a trained on %d runs", k,
                 ", ".join(p.name for p in config.control.plants), n_runs)
        settings = replace(config.control, mpc_model=str(model_dir), out=out / "control" / f"r{k}",
                           save_fem_runs=runs_dir, run_tag=f"r{k}", progress=False)
        episodes = control.run(settings)
        new = [Path(e.row["fem_run"]) for e in episodes if e.row.get("fem_run")]
        result = {"round": k, "train_runs": n_runs, "train_transitions": n_transitions, "new_runs": len(new),
                  **model_error(model, new), **closed_loop([e.row for e in episodes])}
        rows.append(result)
        log.info("dagger round %d: model error on the new runs %.4f mm (max), closed loop settled %s, overshoot "
                 "%.4f mm", k, result["model_max_abs_x_error_mm"], result["settled"], result["overshoot_mm_mean"])
        if not improved(result, best):
            log.info("dagger: round %d did not improve the closed loop; stopping", k)
            break
        best = result
        aggregated += new
        if k + 1 < config.rounds:
            model_dir = out / "models" / f"r{k + 1}"
            model, n_transitions, n_runs = train_model(ramps, config.train, config.val, training, aggregated,
                                                       model_dir)
    write_csv(out / "dagger.csv", rows, list(COLUMNS))
    write_text(out / "dagger.md", summary_table(rows) + "\n")
    return rows


def summary_table(rows: list[dict]) -> str:
    return markdown_table(rows, [
        ("round", "round", "d"), ("training runs", "train_runs", "d"), ("new closed-loop runs", "new_runs", "d"),
        ("f_a on them: max abs x error (mm)", "model_max_abs_x_error_mm", ".4f"),
        ("mean abs x error (mm)", "model_mae_x_mm", ".4f"), ("% of travel", "model_x_error_pct_travel", ".2f"),
        ("reached", "reached", "s"), ("settled", "settled", "s"), ("overshoot mean (mm)", "overshoot_mm_mean", ".4f"),
        ("hold max error mean (mm)", "hold_max_abs_error_mm_mean", ".4f"),
        ("final error mean (mm)", "final_abs_error_mm_mean", ".4f")])
