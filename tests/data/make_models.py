"""Make the committed surrogate models of the control tests: ``tests/data/models/<kind>/``.

The control tests (the MPC, its native solver, the inference, the filters) are written for
particular weights: a closed loop that stalls, creeps or recovers φ does so on one model and
not on a slightly different one. A training run is chaotic in its last bits, and the same seed
gives other weights on other CPUs, so these tests load models trained once and committed
instead of training them in the session. The surrogate tests that test the training itself
keep training in the session (the ``trained`` fixture).

Each model is the ``trained`` fixture's training of its kind (``tests.conftest.QUICK``, on the
committed sweep's C1, validated on C2, one thread) saved as ``deapull train`` saves a model:
``model.pt``, ``model.json`` (its card records the sweep files' sha256, which
``tests/surrogate/test_committed_models.py`` checks against ``tests/data/sweep``) and
``history.csv``, about 250 kB for the three.

Usage (``make test-data`` runs it after the sweep)::

    python tests/data/make_models.py

The models change only when the sweep or the training does; rerun this then, run the tests
and commit the files.
"""
from __future__ import annotations

import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
#: the kinds the control tests load
KINDS = ("f-coulomb", "f-memory", "f-patch")


def main() -> int:
    sys.path.insert(0, str(REPO))
    from tests.conftest import MODELS, QUICK, SWEEP   # pins torch's code paths before torch loads
    import torch

    from deapull.surrogate import store
    from deapull.surrogate.data import load_sweep
    from deapull.surrogate.train import TrainConfig, train
    torch.set_num_threads(1)
    sweep = load_sweep(SWEEP, ["C1", "C2"])
    for kind in KINDS:
        result = train(TrainConfig(kind=kind, **QUICK[kind]), [sweep["C1"]], sweep["C2"])
        folder = store.save(result.model, MODELS / kind, result.summary(), result.history)
        print(f"{folder.relative_to(REPO)}: best epoch {result.best_epoch}, validation loss {result.best_val_loss:.3g}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
