"""Check the layer contract (``[tool.importlinter]`` in pyproject.toml) on the installed layout.

The stage folders sit at the repository's top level and install as ``deapull.<stage>``
through setuptools' package-dir mapping, which import-linter cannot follow on disk. This
script copies the Python files into the layout they install as (a temporary
``deapull/`` tree, read from the mapping itself) and runs ``lint-imports`` there::

    .venv/bin/python scripts/check_layers.py        # exit 0: every import points down

``tests/deapull/test_layers.py`` runs it, and runs it again with one upward import added
to show that the contract catches it.
"""
from __future__ import annotations

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


def main() -> int:
    with tempfile.TemporaryDirectory(prefix="deapull-layers-") as tmp:
        proc = lint(assemble(Path(tmp)))
    print(proc.stdout + proc.stderr, end="")
    return proc.returncode


if __name__ == "__main__":
    raise SystemExit(main())
