"""Check the import structure on the installed layout: the layer contract
(``[tool.importlinter]`` in pyproject.toml) and no import cycle anywhere, inside a layer too.

The stage folders sit at the repository's top level and install as ``deapull.<stage>``
through setuptools' package-dir mapping, which import-linter cannot follow on disk. This
script copies the Python files into the layout they install as (a temporary
``deapull/`` tree, read from the mapping itself), runs ``lint-imports`` there, and looks
for cycles in the import graph (grimp's, the graph import-linter checks; imports inside
functions count)::

    .venv/bin/python scripts/check_layers.py        # exit 0: every import points down, no cycle

``tests/deapull/test_layers.py`` runs both, and runs them again with one upward import
added, and on a small package with a cycle, to show that each check catches its fault.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def assemble(dest: Path, repo: Path = REPO) -> Path:
    """Copy every mapped package's ``*.py`` files to ``dest/<package path>``; returns ``dest``."""
    config = tomllib.loads((repo / "pyproject.toml").read_text())
    mapping = config["tool"]["setuptools"]["package-dir"]
    for package, folder in mapping.items():
        target = dest.joinpath(*package.split("."))
        target.mkdir(parents=True, exist_ok=True)
        for source in (repo / folder).glob("*.py"):
            shutil.copy2(source, target / source.name)
    return dest


def lint(tree: Path, repo: Path = REPO) -> subprocess.CompletedProcess:
    """Run ``lint-imports`` with the repository's contract on an assembled tree."""
    exe = Path(sys.executable).with_name("lint-imports")
    env = dict(os.environ, PYTHONPATH=str(tree))
    return subprocess.run([str(exe), "--config", str(repo / "pyproject.toml"), "--no-cache"], cwd=tree, env=env,
                          capture_output=True, text=True, timeout=300)


#: run in a subprocess with the tree first on the path: prints the import cycles as JSON
_CYCLES = r"""
import json, sys
import grimp
graph = grimp.build_graph(sys.argv[1], cache_dir=None)
edges = {m: sorted(graph.find_modules_directly_imported_by(m)) for m in sorted(graph.modules)}
index, low, stack, on_stack, components = {}, {}, [], set(), []
def visit(v):
    index[v] = low[v] = len(index)
    stack.append(v); on_stack.add(v)
    for w in edges[v]:
        if w not in index:
            visit(w); low[v] = min(low[v], low[w])
        elif w in on_stack:
            low[v] = min(low[v], index[w])
    if low[v] == index[v]:
        component = []
        while True:
            w = stack.pop(); on_stack.discard(w); component.append(w)
            if w == v:
                break
        if len(component) > 1:
            components.append(sorted(component))
sys.setrecursionlimit(10000)
for v in edges:
    if v not in index:
        visit(v)
cycles = []
for component in components:   # one closed path through each strongly connected set
    a = component[0]
    b = next(w for w in edges[a] if w in component)
    cycles.append([a, *graph.find_shortest_chain(importer=b, imported=a)])
print(json.dumps(cycles))
"""


def cycles(tree: Path, package: str = "deapull") -> list[list[str]]:
    """The import cycles of ``package`` in an assembled tree: one closed path
    ``[a, b, ..., a]`` per set of modules that import each other round."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    proc = subprocess.run([sys.executable, "-c", _CYCLES, package], cwd=tree, env=env, capture_output=True,
                          text=True, timeout=300)
    if proc.returncode != 0:
        raise RuntimeError(f"import graph of {package!r} in {tree}: {proc.stderr[-2000:]}")
    return json.loads(proc.stdout)


def check(tree: Path) -> int:
    """Lint the layers and look for cycles in an assembled tree; print both; 0 when both pass."""
    proc = lint(tree)
    found = cycles(tree)
    print(proc.stdout + proc.stderr, end="")
    for cycle in found:
        print("import cycle: " + " -> ".join(cycle))
    print(f"{len(found)} import cycle(s)")
    return proc.returncode or (1 if found else 0)


def main() -> int:
    with tempfile.TemporaryDirectory(prefix="deapull-layers-") as tmp:
        return check(assemble(Path(tmp)))


if __name__ == "__main__":
    raise SystemExit(main())
