"""The presets' models are committed (control/models): the published control figures name the
files they were made with, and those are the files in the repository."""
import json
import tomllib

import pytest

from deapull.provenance import file_sha256
from deapull.surrogate import store
from tests.conftest import REPO

PRESETS = REPO / "control" / "presets"
#: the published figures that name their models
PUBLISHED = {"surrogate": REPO / "bench" / "reference" / "control_surrogate.json",
             "fem": REPO / "bench" / "reference" / "control_fem.json",
             "fem-multi": REPO / "bench" / "reference" / "control_fem_multi.json"}
F_A = {f"C{i}{s}" for i in range(3, 8) for s in ("", "_fast")}


def _folders(preset: str) -> dict:
    control = tomllib.loads((PRESETS / f"{preset}.toml").read_text())["control"]
    out = {"fa": REPO / control["mpc_model"]}
    if any(p.startswith("surrogate:") for p in control["plant"].split(",")):
        out.update({f"fs{n}": REPO / control["plant_model"].format(n=n, setup=f"C{n}") for n in (1, 2)})
    return out


@pytest.mark.parametrize("preset, name, kind, train", [
    ("surrogate", "fs1", "f-coulomb", {"C1", "C1_fast"}), ("surrogate", "fs2", "f-coulomb", {"C2", "C2_fast"}),
    ("surrogate", "fa", "f-coulomb", F_A), ("fem", "fa", "f-memory", {f"C{i}" for i in range(3, 8)})])
def test_the_presets_models_are_committed_and_say_what_they_were_trained_on(preset, name, kind, train):
    folder = _folders(preset)[name]
    assert folder.is_relative_to(REPO / "control" / "models"), folder
    _, meta = store.load(folder)
    assert meta["kind"] == kind and set(meta["card"]["training_coins"]) == train


@pytest.mark.parametrize("published", sorted(PUBLISHED))
def test_the_published_control_figures_were_made_with_the_committed_models(published):
    inputs = json.loads(PUBLISHED[published].read_text())["inputs"]["models"]
    preset = published.split("-")[0]
    assert {str(f.relative_to(REPO)) for f in _folders(preset).values()} == set(inputs)
    for folder, sha in inputs.items():
        assert file_sha256(REPO / folder / store.STATE) == sha, folder
