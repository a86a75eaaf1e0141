"""Sub-commands of the surrogate stage: ``train``, ``evaluate`` and ``experiments``.

Each command function takes the parsed ``argparse.Namespace`` and returns an exit code;
bad input raises :class:`deapull.errors.InputError` (a ``ValueError``), which the
``deapull`` entry point prints and maps to exit status 2.
"""
from __future__ import annotations

import argparse
from pathlib import Path


def _config(args, kind: str):
    import torch

    from deapull.surrogate.train import TrainConfig
    from deapull.errors import InputError
    if args.threads < 1:
        raise InputError(f"--threads {args.threads} must be at least 1")
    torch.set_num_threads(args.threads)
    return TrainConfig(kind=kind, epochs=args.epochs, seed=args.seed, device=args.device, patience=args.patience,
                       batch_size=args.batch_size, lr=args.lr)


def cmd_train(args) -> int:
    from deapull.surrogate import store
    from deapull.surrogate.data import load_sweep, parse_setups
    from deapull.surrogate.train import train
    config = _config(args, args.model)
    train_names = parse_setups(args.train)
    data = load_sweep(args.data, list(dict.fromkeys([*train_names, args.val])))
    result = train(config, [data[n] for n in train_names], data[args.val])
    out = store.save(result.model, args.out, result.summary(), result.history)
    print(f"trained {args.model} on {','.join(train_names)} (val {args.val}): best val loss "
          f"{result.best_val_loss:.4g} at epoch {result.best_epoch}/{len(result.history)}, "
          f"{result.wall_time_s:.1f} s -> {out}")
    return 0


def cmd_evaluate(args) -> int:
    from deapull.io import write_json
    from deapull.surrogate import store
    from deapull.surrogate.data import load_setup
    from deapull.surrogate.evaluate import evaluate, format_table
    model, meta = store.load(args.model)
    data = load_setup(Path(args.data) / f"{args.test}.nc")
    phi = model.phi_of(data)        # the test coin
    ev = evaluate(model, data, engine=args.engine, strict=args.strict, phi=phi)
    print(format_table([ev.metrics]))
    out = Path(args.out) if args.out else Path(args.model) / f"evaluate_{args.test}.json"
    write_json(out, {**ev.metrics, "model_dir": str(args.model), "data_file": str(data.path),
                     "phi": {f: phi.value(f) for f in model.phi_fields},
                     "trained_on": meta.get("training", {}).get("setups", {})}, indent=2)
    print(f"wrote {out}")
    return 0


def cmd_experiments(args) -> int:
    from deapull.surrogate import experiments
    from deapull.surrogate.data import parse_setups
    from deapull.surrogate.models import KINDS
    from deapull.errors import InputError
    kinds = parse_setups(args.models) if args.models else list(KINDS)
    try:
        sets = [int(s) for s in args.sets.split(",") if s.strip()]
    except ValueError:
        raise InputError(f"--sets {args.sets!r}: expected comma-separated set numbers 1..6") from None
    rows = experiments.run(args.data, args.out, _config(args, "f"), kinds=kinds, sets=sets)
    print(experiments.summary_table(rows, kinds))
    print()
    print(experiments.per_set_table(rows, kinds))
    print(f"wrote {args.out}/experiments.csv, table.txt, x_error_boxplot.png, rollouts.png")
    return 0


def _training_args(p: argparse.ArgumentParser, epochs: int) -> None:
    p.add_argument("--epochs", type=int, default=epochs, help=f"most passes over the data (default {epochs})")
    p.add_argument("--patience", type=int, default=100, help="early stopping: passes without improvement (100)")
    p.add_argument("--batch-size", type=int, default=256, help="transitions per Adam step (256)")
    p.add_argument("--lr", type=float, default=1e-3, help="Adam learning rate (1e-3)")
    p.add_argument("--seed", type=int, default=0, help="seed of weights and shuffling (0)")
    p.add_argument("--device", default="cpu", choices=("cpu", "cuda"), help="training device (cpu)")
    p.add_argument("--threads", type=int, default=1,
                   help="torch CPU threads (default 1: the networks are small, more threads only add overhead)")


def register(sub) -> None:
    """Add ``train``, ``evaluate`` and ``experiments`` to the ``deapull`` sub-parsers."""
    from deapull.surrogate.models import KINDS

    p = sub.add_parser("train", help="train a surrogate (f, f-coulomb, nn, lstm) on FEM datasets")
    p.add_argument("--data", required=True, help="folder with <setup>.nc datasets")
    p.add_argument("--train", required=True, help="training setup(s), e.g. C1 or C1,C2")
    p.add_argument("--val", required=True, help="validation setup for early stopping, e.g. C2")
    p.add_argument("--model", required=True, choices=list(KINDS), help="model kind")
    p.add_argument("--out", required=True, help="output folder (model.pt, model.json, history.csv)")
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

    p = sub.add_parser("experiments", help="the paper's six sets {C_i, C_i+1, C_i+2} for every model")
    p.add_argument("--data", required=True, help="folder with C1.nc .. C8.nc")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--models", default="", help=f"comma-separated kinds (default all: {','.join(KINDS)})")
    p.add_argument("--sets", default="1,2,3,4,5,6", help="which sets to run (default 1,2,3,4,5,6)")
    _training_args(p, 1000)
    p.set_defaults(func=cmd_experiments)
