"""The TorchScript export of f-coulomb: a saved file, loaded without deapull's classes, rolls
out as the model does."""
import pytest
import torch

from deapull.errors import InputError
from deapull.surrogate import export
from deapull.surrogate.rollout import rollout


def test_the_exported_rollout_equals_the_eager_one(tmp_path, sweep, trained):
    model = trained("f-coulomb").model
    path = export.export(model, tmp_path / export.EXPORT, card={"kind": model.kind})
    module, card = export.load(path)
    assert card == {"kind": "f-coulomb"}
    for name in ("C3", "C8"):                      # the training coin is C1: others, heavier and lighter
        data = sweep[name]
        phi = model.phi_of(data)
        with torch.no_grad():
            eager = rollout(model, phi, data.states()[0], data.actions(), engine="torch")
            states, forces = module(torch.as_tensor(data.states()[0]), torch.as_tensor(data.actions()),
                                    torch.tensor([data.mass_kg, data.mu_b, data.mu_t], dtype=torch.float64))
        assert states.shape == (data.n_steps, 2) and forces.shape == (data.n_steps - 1, 2)
        assert float(eager.states[0, :, 0].abs().max()) > 1e-4      # the coin moves
        assert float((states[:, 0] - eager.states[0, :, 0].double()).abs().max()) <= 1e-9
        assert float((forces - eager.forces[0].double()).abs().max()) <= 1e-9


def test_only_f_coulomb_is_exported(tmp_path, trained):
    with pytest.raises(InputError, match="'nn' has no TorchScript export"):
        export.export(trained("nn").model, tmp_path / "nn.ts")
    assert not (tmp_path / "nn.ts").exists()


def test_a_missing_export_is_named(tmp_path):
    with pytest.raises(InputError, match="no such exported model"):
        export.load(tmp_path / "none.ts")


def test_deapull_export_writes_the_file_with_its_card(tmp_path, trained):
    from deapull.surrogate import store
    from deapull.workflows.cli import main
    result = trained("f-coulomb")
    folder = store.save(result.model, tmp_path / "m", result.summary(), result.history)
    assert main(["export", "--model", str(folder)]) == 0
    _, card = export.load(folder / export.EXPORT)
    assert card["kind"] == "f-coulomb" and card["training_coins"] == ["C1"]
