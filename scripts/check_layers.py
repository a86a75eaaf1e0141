"""Check the layer contract (``[tool.importlinter]`` in pyproject.toml) on the installed layout.

The stage folders sit at the repository's top level and install as ``deapull.<stage>``
through setuptools' package-dir mapping, which import-linter cannot follow on disk. This
script copies the Python files into the layout they install as (a temporary
``deapull/`` tree, read from the mapping itself) and runs ``lint-imports`` there::

    .venv/bin/python scripts/check_layers.py        # exit 0: every import points down

``tests/deapull/test_layers.py`` runs it, and runs it again with one upward import added
to show that the contract catches it.

import-linter's layers contract says nothing about arrows *inside* one layer, so the
script also looks for import cycles between the modules of the assembled tree
(:func:`cycles`: every ``import``/``from ... import`` of a ``deapull`` module, at module or
function level, read with :mod:`ast`; strongly connected components of that graph) and
fails on any::

    .venv/bin/python scripts/check_layers.py        # exit 1 and the cycle when one exists
"""
from __future__ import annotations

import ast
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


def _module_name(tree: Path, path: Path) -> str:
    parts = list(path.relative_to(tree).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph(tree: Path, root: str = "deapull") -> dict[str, set[str]]:
    """Module → the ``root`` modules it imports (anywhere in the file), on an assembled tree."""
    modules = {_module_name(tree, p): p for p in (tree / root).rglob("*.py")}
    graph: dict[str, set[str]] = {name: set() for name in modules}
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join(anchor + ([base] if base else []))
                # ``from pkg import mod`` imports the module pkg.mod when there is one
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
            for target in targets:
                while target and target not in modules:     # deapull.x.y.Name -> deapull.x.y
                    target = target.rpartition(".")[0]
                if target and target != name and not name.startswith(target + "."):
                    graph[name].add(target)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import cycles of ``graph``: its strongly connected components of more than one module
    (Tarjan), each sorted; the list sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(found)


def main() -> int:
    with tempfile.TemporaryDirectory(prefix="deapull-layers-") as tmp:
        tree = assemble(Path(tmp))
        proc = lint(tree)
        found = cycles(import_graph(tree))
    print(proc.stdout + proc.stderr, end="")
    for cycle in found:
        print("import cycle: " + " <-> ".join(cycle))
    print(f"{len(found)} import cycle(s) inside the layers")
    return proc.returncode or (1 if found else 0)


if __name__ == "__main__":
    raise SystemExit(main())
