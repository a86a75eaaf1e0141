"""The layers import only downward: the import-linter contract of pyproject.toml holds on the
installed layout, and it does catch an arrow that points up."""
import importlib.util
import sys

import pytest

from tests.conftest import REPO

sys.path.insert(0, str(REPO / "scripts"))
check_layers = pytest.importorskip("check_layers")

pytestmark = pytest.mark.skipif(importlib.util.find_spec("importlinter") is None,
                                reason="import-linter is not installed (make setup installs it)")


def test_every_import_points_down(tmp_path):
    proc = check_layers.lint(check_layers.assemble(tmp_path))
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-2000:]
    assert "1 kept, 0 broken" in proc.stdout


@pytest.mark.parametrize("lower, upper", [("meshing/groups.py", "deapull.workflows.cli"),
                                          ("fem_solver/coin.py", "deapull.surrogate.data"),
                                          ("dataset.py", "deapull.fem_solver.stepping")])
def test_an_upward_import_breaks_the_contract(tmp_path, lower, upper):
    tree = check_layers.assemble(tmp_path)
    path = tree / "deapull" / lower
    path.write_text(path.read_text() + f"\nimport {upper}  # an arrow that points up\n")
    proc = check_layers.lint(tree)
    assert proc.returncode != 0 and "BROKEN" in proc.stdout, proc.stdout[-2000:]
    assert upper in proc.stdout


def test_no_import_cycle_inside_a_layer(tmp_path):
    """Arrows inside one layer may not close a circle (the layers contract cannot see them)."""
    tree = check_layers.assemble(tmp_path)
    assert check_layers.cycles(check_layers.import_graph(tree)) == []


@pytest.mark.parametrize("module, imports, expected", [
    # a function-level import back up the chain mpc_policy -> native -> dynamics
    ("control/dynamics.py", "    from deapull.control import mpc_policy\n",
     ["deapull.control.dynamics", "deapull.control.inference", "deapull.control.mpc_policy",
      "deapull.control.native", "deapull.control.rollout_inference"]),
    # a relative import inside the surrogate layer
    ("surrogate/phi.py", "from .models import base\n", None),
])
def test_a_circle_inside_a_layer_is_found(tmp_path, module, imports, expected):
    tree = check_layers.assemble(tmp_path)
    path = tree / "deapull" / module
    body = "\n\ndef _closes_a_circle():\n" + imports if imports.startswith("    ") else "\n" + imports
    path.write_text(path.read_text() + body)
    found = check_layers.cycles(check_layers.import_graph(tree))
    assert found, "the circle was not found"
    if expected is not None:
        assert expected in found
    assert any(module.replace("/", ".").removesuffix(".py") in m for c in found for m in c)


def test_cycles_on_a_known_graph():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": {"e"}, "f": set()}
    assert check_layers.cycles(graph) == [["a", "b", "c"]]
