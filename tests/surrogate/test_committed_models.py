"""The control tests' committed models (tests/data/models, made by tests/data/make_models.py)
are what that script makes from the committed sweep: each card records the sweep files it was
trained on, and the configuration is the ``trained`` fixture's. A sweep regenerated without
them, or a changed quick training, fails here, not as a puzzling control test."""
from __future__ import annotations

import json

import pytest

from tests.conftest import MODELS, QUICK
from tests.data.make_models import KINDS


@pytest.mark.parametrize("kind", KINDS)
def test_a_committed_model_was_trained_on_the_committed_sweep_as_the_fixture_trains(sweep, committed, kind):
    meta = json.loads((MODELS / kind / "model.json").read_text())
    assert meta["card"]["datasets"] == {"C1": sweep["C1"].sha256, "C2": sweep["C2"].sha256}, \
        f"{MODELS / kind} was trained on other data than tests/data/sweep; run `make test-data`"
    config = meta["training"]["config"]
    assert config["kind"] == kind and all(config[k] == v for k, v in QUICK[kind].items()), config
    assert committed(kind).kind == kind
