"""The ``deapull`` entry point: a first run is quiet, ``-v`` shows the compiler's detail."""
import os
import subprocess
import sys

import pytest

from tests.conftest import REPO, TINY_MESH

pytestmark = pytest.mark.fem


def _solve(tmp_path, *flags):
    """free_bending on a tiny mesh with an empty form cache, as on a fresh machine."""
    cmd = [sys.executable, "-m", "deapull.workflows", *flags, "solve", "--scene", "free_bending", "--out",
           str(tmp_path / "out"), "--set", "load.end_time_s=0.01", "--set", "load.ramp_time_s=0.01",
           "--set", "time.dt_max_s=0.005", "--set", "time.dt_initial_s=0.005"]
    for o in TINY_MESH:
        cmd += ["--set", o]
    env = dict(os.environ, XDG_CACHE_HOME=str(tmp_path / "cache"))   # FFCx compiles every form anew
    proc = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return [line for line in proc.stderr.splitlines() if line.strip() and "%|" not in line]


def test_first_run_is_quiet(tmp_path):
    """FFCx compiles every form (cffi -> setuptools -> gcc, each logging at INFO); none of it shows."""
    quiet = _solve(tmp_path / "a")
    others = [line for line in quiet if " deapull." not in line]
    assert not others, others[:5]                                    # only our own log lines


def test_verbose_shows_other_libraries_info(capfd):
    """What -v changes: another library's INFO line (as setuptools logs its gcc calls) shows."""
    import logging

    from deapull.workflows.cli import setup_logging
    try:
        for verbose in (False, True):
            setup_logging(verbose)
            logging.getLogger().setLevel(logging.INFO)          # what importing setuptools does
            logging.getLogger("compilers.C.base").info("gcc -shared forms.o (verbose=%s)", verbose)
            logging.getLogger("deapull.x").info("ours (verbose=%s)", verbose)
        err = capfd.readouterr().err
    finally:
        logging.basicConfig(force=True, handlers=[logging.NullHandler()])
    assert "ours (verbose=False)" in err and "ours (verbose=True)" in err
    assert "gcc -shared forms.o (verbose=False)" not in err and "gcc -shared forms.o (verbose=True)" in err
