"""A trained model on disk: ``model.pt`` (torch state dict) + ``model.json`` + ``history.csv``.

``model.json`` holds everything needed to rebuild the model and to read it without torch:
its kind and hyper-parameters, the normalisation of the training data, the training input
range, the setups it saw (file, SHA-256, fidelity, φ, V^T), the training configuration and
outcome, the model card (:mod:`deapull.surrogate.card`) and the package versions. Infinite values (e.g. no contact loss) are written as ``null``. Every
file is written atomically (:func:`deapull.io.atomic_write`).

A model holds no φ: the coin is an argument of every step. Folders saved while φ was
part of the model (same format) still load: their φ entries of the state dict
(:data:`LEGACY_PHI_KEYS`) are dropped, and the paper model's old hyper-parameter ``law``
is accepted.
"""
from __future__ import annotations

import json
import math
import platform
from pathlib import Path

import numpy as np
import torch

from deapull.errors import InputError
from deapull.io import atomic_write, write_csv, write_text
from deapull.surrogate import card
from deapull.surrogate.models import InputRange, Normalisation, Surrogate, build

FORMAT = "deapull-surrogate/1"
STATE, META, HISTORY = "model.pt", "model.json", "history.csv"
#: state-dict entries of φ in folders saved before φ became an argument of the step
LEGACY_PHI_KEYS = ("mass_kg", "mu_b", "mu_t", "v_threshold_V")


class ModelFileError(InputError):
    """A model folder that cannot be read back; the message names the file."""


def save(model: Surrogate, out_dir: str | Path, training: dict | None = None, history: list | None = None,
         test: dict | None = None) -> Path:
    """Write ``model`` to ``out_dir`` (created); returns the folder.

    Parameters
    ----------
    model : Surrogate
    out_dir : str or pathlib.Path
    training : dict, optional
        What :meth:`surrogate.train.TrainResult.summary` returns (setups, configuration...).
    history : list of dict, optional
        Per-epoch losses, written as CSV.
    test : dict, optional
        The metrics of a test rollout (:func:`surrogate.evaluate.evaluate`), kept in the card.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    meta = {"format": FORMAT, "kind": model.kind, "hyper_parameters": model.hparams,
            "normalisation": model.norm.to_dict(), "input_range": model.input_range.to_dict(),
            "training": training or {}, "card": card.build(training, test) if training else {}, "versions": {"python": platform.python_version(),
                                                     "torch": torch.__version__, "numpy": np.__version__}}
    atomic_write(out / STATE, lambda p: torch.save(model.state_dict(), p))
    write_text(out / META, json.dumps(_finite(meta), indent=2) + "\n")
    if history:
        write_csv(out / HISTORY, history, list(history[0]))
    return out


def kind_of(model_dir: str | Path) -> str | None:
    """The model kind a saved folder holds (``model.json``'s ``kind``), read without torch or the
    weights; None when the folder has no ``model.json``."""
    path = Path(model_dir) / META
    if not path.is_file():
        return None
    try:
        return json.loads(path.read_text()).get("kind")
    except json.JSONDecodeError as err:
        raise ModelFileError(f"{path}: not valid JSON ({err})") from err


def load(model_dir: str | Path) -> tuple[Surrogate, dict]:
    """Rebuild a saved model (on the CPU, in eval mode) and return it with its JSON."""
    folder = Path(model_dir)
    for name in (META, STATE):
        if not (folder / name).is_file():
            raise ModelFileError(f"{folder / name}: missing; is {folder} a folder written by `deapull train`?")
    try:
        meta = json.loads((folder / META).read_text())
    except json.JSONDecodeError as err:
        raise ModelFileError(f"{folder / META}: not valid JSON ({err})") from err
    if meta.get("format") != FORMAT:
        raise ModelFileError(f"{folder / META}: format {meta.get('format')!r}, expected {FORMAT!r}")
    hparams = {k: (math.inf if k == "v_contact_loss_V" and v is None else v)
               for k, v in meta["hyper_parameters"].items()}
    rng = {k: meta["input_range"][k] for k in ("low", "high", "tolerance")}
    try:
        model = build(meta["kind"], Normalisation(**meta["normalisation"]), InputRange(**rng), hparams)
    except (TypeError, ValueError) as err:
        raise ModelFileError(f"{folder / META}: cannot rebuild the model ({err})") from err
    state = torch.load(folder / STATE, map_location="cpu", weights_only=True)
    model.load_state_dict({k: v for k, v in state.items() if k not in LEGACY_PHI_KEYS})
    return model.eval(), meta


def _finite(value):
    """JSON-safe copy: non-finite floats become None."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value

