"""Installing deapull shadows nothing: python-control's ``control`` and this project's
``deapull.control`` are both importable, and the project adds no other top-level name."""
import importlib
import importlib.metadata
import json
import subprocess
import sys

import pytest


def test_python_control_and_deapull_control_are_both_importable(tmp_path):
    pytest.importorskip("control", reason="python-control is a test dependency (make setup installs it)")
    code = ("import json, control, deapull.control as ours; "
            "print(json.dumps([control.__file__, hasattr(control, 'tf'), ours.__name__, ours.__file__]))")
    # run outside the checkout, as a user of the installed packages would
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    theirs, has_tf, name, ours = json.loads(proc.stdout)
    assert has_tf and ("site-packages" in theirs or "dist-packages" in theirs), theirs
    assert name == "deapull.control" and ours != theirs


def test_the_distribution_installs_one_top_level_package():
    dist = importlib.metadata.distribution("deapull")
    tops = {p.split(".")[0] for p in dist.read_text("top_level.txt").split()} if dist.read_text("top_level.txt") \
        else None
    if tops is None:   # editable installs may not write top_level.txt: ask the installed finder
        code = ("import importlib.util as u, json; print(json.dumps({n: u.find_spec(n) is not None for n in "
                "('deapull', 'meshing', 'fem_solver', 'surrogate', 'workflows')}))")
        found = json.loads(subprocess.run([sys.executable, "-c", code], cwd="/", capture_output=True, text=True,
                                          check=True).stdout)
        assert found == {"deapull": True, "meshing": False, "fem_solver": False, "surrogate": False,
                         "workflows": False}
    else:
        assert tops == {"deapull"}


PUBLIC = ("deapull", "deapull.meshing", "deapull.fem_solver", "deapull.surrogate", "deapull.control", "deapull.workflows")


@pytest.mark.parametrize("package", PUBLIC)
def test_each_package_names_its_public_api(package):
    """``__all__`` lists names the package has, without duplicates; ``import *`` gives exactly them."""
    if package in ("deapull.meshing", "deapull.fem_solver"):
        pytest.importorskip("dolfinx", reason="the FEM packages need FEniCSx")
    names = importlib.import_module(package).__all__
    assert names and len(set(names)) == len(names)
    scope = {}
    exec(f"from {package} import *", scope)
    assert set(scope) - {"__builtins__"} == set(names)


def test_importing_the_command_line_loads_no_solver_or_network():
    """``deapull.workflows`` (and so ``deapull --help``) loads neither dolfinx, gmsh, torch nor MPI."""
    code = ("import json, sys, deapull.workflows; "
            "print(json.dumps(sorted(m for m in ('dolfinx', 'gmsh', 'torch', 'mpi4py') if m in sys.modules)))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    assert json.loads(proc.stdout) == []
