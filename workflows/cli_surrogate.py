"""Sub-commands of the surrogate stage: ``train``, ``evaluate``, ``experiments`` and
``experiments-protocols``.

Each command function takes the parsed ``argparse.Namespace`` and returns an exit code;
bad input raises :class:`deapull.errors.InputError` (a ``ValueError``), which the
``deapull`` entry point prints and maps to exit status 2.
"""
from __future__ import annotations

import argparse
import csv
import dataclasses
import logging
from pathlib import Path

from deapull.errors import InputError
from deapull.io import write_json, write_text

log = logging.getLogger(__name__)

# lazy imports below: the surrogate modules load torch, which the CLI starts without

#: default --restarts: the seeds trained per model, the best on the validation setup kept
#: (docs/surrogate.md: one seed's error can be 50x another's on the same set). The physics-
#: informed f models train in seconds and get 5; the slower memory model and the black boxes 1.
RESTARTS = "f=5,f-coulomb=5"


def parse_restarts(text: str) -> tuple[int, dict]:
    """``--restarts``: ``N`` (every model) or ``kind=N,...`` (those kinds; every other model 1).
    Returns (the count for a kind not named, {kind: count}); refuses anything else naming the
    flag before any data are read."""
    def count(value: str, where: str) -> int:
        try:
            n = int(value)
        except ValueError:
            n = None
        if n is None or n < 1 or str(n) != value.strip():
            raise InputError(f"--restarts {where}: must be a whole number of at least 1 (how many seeds to train "
                             f"from --seed; the one whose rollout of the validation setup has the lowest x error "
                             f"is kept), or kind=N,... for some models (the rest train once)")
        return n
    text = str(text).strip()
    if "=" not in text:
        return count(text, text), {}
    by_kind = {}
    for item in (part.strip() for part in text.split(",") if part.strip()):
        kind, _, value = item.partition("=")
        by_kind[kind.strip()] = count(value, item)
    return 1, by_kind


def restarts_for(args, kind: str) -> int:
    default, by_kind = parse_restarts(args.restarts)
    return by_kind.get(kind, default)


def _config(args, kind: str):
    import torch  # lazy: torch

    from deapull.surrogate.models import KINDS  # lazy: torch
    from deapull.surrogate.train import TrainConfig  # lazy: torch
    unknown = [k for k in parse_restarts(args.restarts)[1] if k not in KINDS]
    if unknown:
        raise InputError(f"--restarts {args.restarts}: {', '.join(unknown)} is not a model; choose from "
                         f"{', '.join(KINDS)}")
    if args.threads < 1:
        raise InputError(f"--threads {args.threads} must be at least 1")
    torch.set_num_threads(args.threads)
    return TrainConfig(kind=kind, epochs=args.epochs, seed=args.seed, device=args.device, patience=args.patience,
                       batch_size=args.batch_size, lr=args.lr, restarts=restarts_for(args, kind))


def extra_runs(folders, train_names: list[str], val_name: str) -> list[tuple[str, Path, str]]:
    """The runs ``<folder>/<setup>_<name>.nc`` of the training and validation setups, as (setup,
    path, role) with role ``train`` or ``val``, in order.

    Raises
    ------
    InputError
        When a folder is missing, or holds no run of any training setup (naming the folder, the
        setups and the file names it looked for).
    """
    out = []
    for folder in map(Path, folders):
        if not folder.is_dir():
            raise InputError(f"--runs {folder}: no such folder")
        found = []
        for name, role in [*((n, "train") for n in train_names), (val_name, "val")]:
            found += [(name, path, role) for path in sorted(folder.glob(f"{name}_*.nc"))]
        if not any(role == "train" for _, _, role in found):
            raise InputError(f"--runs {folder}: no run of the training setups {','.join(train_names)} "
                             f"(files named <setup>_<name>.nc, e.g. {train_names[0]}_fast.nc)")
        out += found
    names = [path.stem for _, path, _ in out]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise InputError(f"--runs: the run {twice[0]} is in more than one folder; a run's name must be unique")
    return out


def cmd_train(args) -> int:
    from deapull.surrogate import store  # lazy: torch
    from deapull.surrogate.data import load_sweep, parse_setups  # lazy: torch
    from deapull.surrogate.train import train  # lazy: torch
    config = _config(args, args.model)
    train_names = parse_setups(args.train)
    extra = extra_runs(args.runs or [], train_names, args.val)     # refuses before any loading
    data = load_sweep(args.data, list(dict.fromkeys([*train_names, args.val])))
    train_sets, val_sets = [data[n] for n in train_names], [data[args.val]]
    phis = None
    if extra:
        from deapull.surrogate.data import load_setup  # lazy: torch
        from deapull.surrogate.protocol_experiments import coin_phi  # lazy: torch
        # a run's coin is its setup's: φ from the setup's ramp (a release run alone does not give V^T)
        coins = {coin: coin_phi(args.model, data[coin]) for coin, _, _ in extra}
        phis = {path.stem: coins[coin] for coin, path, _ in extra if coins[coin] is not None}
        for coin, path, role in extra:
            (train_sets if role == "train" else val_sets).append(dataclasses.replace(load_setup(path), extra=True))
        log.info("extra runs: %s", ", ".join(f"{path.stem} ({role})" for _, path, role in extra))
    result = train(config, train_sets, val_sets, phis=phis)
    out = store.save(result.model, args.out, result.summary(), result.history)
    scores = ", ".join(f"{r['seed']}: {r['val_x_error_pct']:.3g} %" for r in result.restarts)
    trained, validated = (",".join(d.name for d in sets) for sets in (train_sets, val_sets))
    print(f"trained {args.model} on {trained} (val {validated}): kept seed {result.seed} of "
          f"{len(result.restarts)} (validation rollout x error by seed: {scores}); best val loss "
          f"{result.best_val_loss:.4g} at epoch {result.best_epoch}/{len(result.history)}, "
          f"{result.wall_time_s:.1f} s -> {out}")
    return 0


def cmd_evaluate(args) -> int:
    from deapull.surrogate import store  # lazy: torch
    from deapull.surrogate.data import load_setup  # lazy: torch
    from deapull.surrogate.evaluate import evaluate, format_table  # lazy: torch
    from deapull.surrogate import card  # lazy: torch
    model, meta = store.load(args.model)
    data = load_setup(Path(args.data) / f"{args.test}.nc")
    mismatches = card.check(meta.get("card", {}), data)
    for message in mismatches:
        log.warning("%s", message)
    phi = model.phi_of(data)        # the test coin
    ev = evaluate(model, data, engine=args.engine, strict=args.strict, phi=phi)
    print(format_table([ev.metrics]))
    out = Path(args.out) if args.out else Path(args.model) / f"evaluate_{args.test}.json"
    write_json(out, {**ev.metrics, "model_dir": str(args.model), "data_file": str(data.path),
                     "phi": {f: phi.value(f) for f in model.phi_fields},
                     "trained_on": meta.get("training", {}).get("setups", {}), "card_warnings": mismatches},
               indent=2)
    print(f"wrote {out}")
    return 0


def _publish(args, source: Path, name: str) -> None:
    """``--publish DIR``: copy a run's results file to DIR/``name`` (atomically; the docs' tables
    are generated from bench/reference)."""
    if args.publish:
        target = write_text(Path(args.publish) / name, source.read_text())
        print(f"published {target}")


def cmd_export(args) -> int:
    from deapull.surrogate import export, store  # lazy: torch
    model, meta = store.load(args.model)
    out = Path(args.out) if args.out else Path(args.model) / export.EXPORT
    export.export(model, out, card={"kind": model.kind, **meta.get("card", {})})
    print(f"wrote {out}: torch.jit.load(path)(s0, actions, phi) -> (states, forces); s0 (2,) = (x m, u m/s), "
          "actions (T, 2) = (V, dt s), phi (3,) = (m_c kg, mu_b, mu_t), float64")
    return 0


def cmd_experiments(args) -> int:
    from deapull.surrogate import experiments  # lazy: torch
    from deapull.surrogate.data import parse_setups  # lazy: torch
    kinds = parse_setups(args.models) if args.models else list(experiments.SET_KINDS)
    try:
        sets = [int(s) for s in args.sets.split(",") if s.strip()]
    except ValueError:
        raise InputError(f"--sets {args.sets!r}: expected comma-separated set numbers 1..6") from None
    restarts = {k: restarts_for(args, k) for k in kinds}
    rows = experiments.run(args.data, args.out, _config(args, "f"), kinds=kinds, sets=sets, restarts=restarts,
                           repeats=args.repeats)
    print(experiments.summary_table(rows, kinds))
    print()
    print(experiments.per_set_table(rows, kinds))
    print(f"wrote {args.out}/experiments.csv, table.txt, summary.json, x_error_boxplot.png, rollouts.png")
    _publish(args, Path(args.out) / experiments.SUMMARY, "surrogate_experiments.json")
    return 0


def cmd_experiments_protocols(args) -> int:
    from deapull.surrogate import experiments, protocol_experiments as pe  # lazy: torch
    from deapull.surrogate.data import parse_setups  # lazy: torch
    if args.held_out_pairs:
        kinds = parse_setups(args.models) if args.models else ["f-coulomb"]
        excitation = Path(args.excitation) if args.excitation else Path(args.data) / "excitation"
        rows = pe.run_pairs(args.data, args.out, _config(args, "f"), kinds=kinds,
                            restarts={k: restarts_for(args, k) for k in kinds},
                            excitation_dir=excitation if excitation.is_dir() else None)
        print(pe.pairs_table(rows, kinds))
        print(f"wrote {args.out}/pairs.csv, pairs.md, pairs.json")
        _publish(args, Path(args.out) / "pairs.json", "surrogate_pairs.json")
        return 0
    kinds = parse_setups(args.models) if args.models else list(pe.DEFAULT_KINDS)
    design = pe.Design(train_coins=tuple(parse_setups(args.train_coins)), val_coins=tuple(parse_setups(args.val_coins)),
                       test_coins=tuple(parse_setups(args.test_coins)) if args.test_coins else (),
                       train_protocols=tuple(parse_setups(args.train_protocols)),
                       test_protocols=tuple(parse_setups(args.test_protocols)))
    restarts = {k: restarts_for(args, k) for k in kinds}
    rows = pe.run(args.data, args.out, _config(args, "f"), excitation_dir=args.excitation, kinds=kinds, design=design,
                  restarts=restarts)
    ramp_csv = Path(args.ramp_results) / "experiments.csv" if args.ramp_results else None
    if ramp_csv is not None and ramp_csv.is_file():
        with ramp_csv.open() as fh:
            ramp_rows = [_typed(r) for r in csv.DictReader(fh)]
        ramp_kinds = [k for k in dict.fromkeys(r["model"] for r in ramp_rows)]
        print(f"Ramps, the paper's six sets ({ramp_csv}):")
        print(experiments.per_set_table(ramp_rows, ramp_kinds))
        print()
    print("Held-out protocols and coins:")
    print(pe.format_text(pe.summarise(rows, kinds), kinds))
    print(f"wrote {args.out}/protocols.csv, protocols.md, protocols.json, protocols.png")
    return 0


def _typed(row: dict) -> dict:
    """A row of experiments.csv with its numbers and booleans back."""
    out = {}
    for k, v in row.items():
        if v in ("True", "False"):
            out[k] = v == "True"
        elif k in ("set",):
            out[k] = int(v)
        else:
            try:
                out[k] = float(v) if v != "" else None
            except ValueError:
                out[k] = v
    return out


def _training_args(p: argparse.ArgumentParser, epochs: int, patience: int = 100) -> None:
    p.add_argument("--epochs", type=int, default=epochs, help=f"most passes over the data (default {epochs})")
    p.add_argument("--patience", type=int, default=patience,
                   help=f"early stopping: passes without improvement ({patience})")
    p.add_argument("--batch-size", type=int, default=256, help="transitions per Adam step (256)")
    p.add_argument("--lr", type=float, default=1e-3, help="Adam learning rate (1e-3)")
    p.add_argument("--seed", type=int, default=0, help="seed of weights and shuffling (0)")
    p.add_argument("--restarts", default=RESTARTS,
                   help=f"seeds trained per model, --seed, --seed+1, ...; the one whose rollout of the validation "
                        f"setup has the lowest x error is kept, the test setup is never looked at: N for every "
                        f"model, or kind=N,... for those kinds (the rest once) (default {RESTARTS}; 1: a single run)")
    p.add_argument("--device", default="cpu", choices=("cpu", "cuda"), help="training device (cpu)")
    p.add_argument("--threads", type=int, default=1,
                   help="torch CPU threads (default 1: the networks are small, more threads only add overhead)")


def register(sub) -> None:
    """Add ``train``, ``evaluate`` and ``experiments`` to the ``deapull`` sub-parsers."""
    from deapull.surrogate.models import KINDS  # lazy: torch

    p = sub.add_parser("train", help=f"train a surrogate ({', '.join(KINDS)}) on FEM datasets")
    p.add_argument("--data", required=True, help="folder with <setup>.nc datasets")
    p.add_argument("--train", required=True, help="training setup(s), e.g. C1 or C1,C2")
    p.add_argument("--val", required=True, help="validation setup for early stopping, e.g. C2")
    p.add_argument("--model", required=True, choices=list(KINDS), help="model kind")
    p.add_argument("--out", required=True, help="output folder (model.pt, model.json, history.csv)")
    p.add_argument("--runs", action="append", metavar="DIR",
                   help="a folder of further runs <setup>_<name>.nc of the same coins (e.g. the excitation set, "
                   "or ramps at another rate): those of the training setups are trained on too, those of the "
                   "validation setup validated on; repeatable")
    _training_args(p, 1000)
    p.set_defaults(func=cmd_train)

    p = sub.add_parser("evaluate", help="1 s rollout of a trained model on a test setup against the FEM")
    p.add_argument("--model", required=True, help="model folder written by `deapull train`")
    p.add_argument("--data", required=True, help="folder with <setup>.nc datasets")
    p.add_argument("--test", required=True, help="test setup, e.g. C3")
    p.add_argument("--out", default=None, help="JSON file (default <model>/evaluate_<test>.json)")
    p.add_argument("--engine", default="auto", choices=("auto", "torch", "native"), help="rollout engine")
    p.add_argument("--strict", action="store_true", help="fail when an input leaves the training range")
    p.set_defaults(func=cmd_evaluate)

    p = sub.add_parser("export", help="a trained f-coulomb model's rollout as one TorchScript file (no deapull needed)")
    p.add_argument("--model", required=True, help="model folder written by `deapull train`")
    p.add_argument("--out", default=None, help="the file (default <model>/model.ts)")
    p.set_defaults(func=cmd_export)

    p = sub.add_parser("experiments", help="the paper's six sets {C_i, C_i+1, C_i+2} for every model")
    p.add_argument("--data", required=True, help="folder with C1.nc .. C8.nc")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--models", default="", help="comma-separated kinds (default: every kind that one training coin "
                   f"identifies, {','.join(k for k, c in KINDS.items() if c.training_coins == 1)}; "
                   f"also {','.join(k for k, c in KINDS.items() if c.training_coins > 1) or 'none'})")
    p.add_argument("--sets", default="1,2,3,4,5,6", help="which sets to run (default 1,2,3,4,5,6)")
    p.add_argument("--publish", default="", help="also copy summary.json to DIR/surrogate_experiments.json "
                   "(bench/reference: the docs' figures)")
    p.add_argument("--repeats", type=int, default=3,
                   help="independent repeats of every model (seeds --seed + r x restarts on): mean and spread (3)")
    _training_args(p, 1000)
    p.set_defaults(func=cmd_experiments)

    p = sub.add_parser("experiments-protocols",
                       help="train on ramps + excitation, test on held-out protocols and coins (docs/surrogate.md)")
    p.add_argument("--data", required=True, help="folder with the ramps C1.nc .. C8.nc")
    p.add_argument("--excitation", default=None,
                   help="folder with <setup>_<protocol>.nc (deapull sweep --protocols excitation; default <data>/excitation)")
    p.add_argument("--out", required=True, help="output folder (resumes: trained models and evaluations are reused)")
    p.add_argument("--models", default="", help="comma-separated kinds (default f-memory,f-coulomb,f,nn,lstm)")
    p.add_argument("--held-out-pairs", action="store_true",
                   help="leave one friction pair out at a time (C1/C2 .. C7/C8), train on two other pairs' ramps, validate "
                   "on the third's first coin, test on the pair's ramps and its excitation runs in --excitation (--models, default f-coulomb; the "
                   "coin and protocol flags are not used)")
    p.add_argument("--publish", default="", help="with --held-out-pairs: also copy pairs.json to "
                   "DIR/surrogate_pairs.json (bench/reference)")
    p.add_argument("--train-coins", default="C1", help="training coins (C1)")
    p.add_argument("--val-coins", default="C3", help="validation coins, early stopping (C3)")
    p.add_argument("--test-coins", default="C5,C7", help="held-out coins tested on every protocol (C5,C7)")
    p.add_argument("--train-protocols", default="ramp,rhr,random1,random2",
                   help="protocols trained on (ramp,rhr,random1,random2)")
    p.add_argument("--test-protocols", default="release,triangle,random3",
                   help="held-out protocols (release,triangle,random3)")
    p.add_argument("--ramp-results", default=None,
                   help="folder of a `deapull experiments` run: its per-set table is printed beside this one")
    _training_args(p, 1000)
    p.set_defaults(func=cmd_experiments_protocols)
