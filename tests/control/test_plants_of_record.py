"""The surrogate preset's plants and f_a are committed (control/models): the published control
figures name the files they were made with, and those are the files in the repository."""
import json
import tomllib

import pytest

from deapull.provenance import file_sha256
from deapull.surrogate import store
from tests.conftest import REPO

PRESET = REPO / "control" / "presets" / "surrogate.toml"
PUBLISHED = REPO / "bench" / "reference" / "control_surrogate.json"


def _preset_folders() -> dict:
    control = tomllib.loads(PRESET.read_text())["control"]
    return {"fs1": REPO / control["plant_model"].format(n=1, setup="C1"),
            "fs2": REPO / control["plant_model"].format(n=2, setup="C2"),
            "fa": REPO / control["mpc_model"]}


@pytest.mark.parametrize("name, train", [("fs1", {"C1", "C1_fast"}), ("fs2", {"C2", "C2_fast"}),
                                         ("fa", {f"C{i}{s}" for i in range(3, 8) for s in ("", "_fast")})])
def test_the_surrogate_presets_models_are_committed_and_say_what_they_were_trained_on(name, train):
    folder = _preset_folders()[name]
    assert folder.is_relative_to(REPO / "control" / "models"), folder
    _, meta = store.load(folder)
    assert meta["kind"] == "f-coulomb" and set(meta["card"]["training_coins"]) == train


def test_the_published_control_figures_were_made_with_the_committed_models():
    inputs = json.loads(PUBLISHED.read_text())["inputs"]["models"]
    folders = _preset_folders()
    assert {str(f.relative_to(REPO)) for f in folders.values()} == set(inputs)
    for folder, sha in inputs.items():
        assert file_sha256(REPO / folder / store.STATE) == sha, folder
