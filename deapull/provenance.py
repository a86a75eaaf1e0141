"""Where a number came from: the git commit and the versions of the packages that made it."""
from __future__ import annotations

import hashlib
import importlib
import platform
import subprocess
from pathlib import Path

#: packages whose versions a dataset or a study records (those installed)
PACKAGES = ("dolfinx", "gmsh", "petsc4py", "numpy", "xarray", "torch")


def package_versions(packages=PACKAGES) -> dict[str, str]:
    """``{"version_python": ..., "version_<pkg>": ...}`` for the installed ``packages``."""
    out = {"version_python": platform.python_version()}
    for name in packages:
        try:
            out[f"version_{name}"] = str(importlib.import_module(name).__version__)
        except ImportError:
            continue
    return out


def file_sha256(path: str | Path) -> str:
    """The SHA-256 of a file's bytes (hex)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def git_commit() -> str:
    """The commit of the checkout this code runs from ("unknown" outside a git checkout)."""
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10,
                             cwd=Path(__file__).parent)
        return out.stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def summary() -> str:
    """One line: git commit and the main package versions (for the head of a study's Markdown)."""
    v = package_versions(("dolfinx", "numpy", "torch"))
    parts = [f"git {git_commit()[:12]}"] + [f"{k[len('version_'):]} {v[k]}" for k in v if k != "version_python"]
    return ", ".join(parts + [f"python {v['version_python']}"])
