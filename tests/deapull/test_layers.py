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
