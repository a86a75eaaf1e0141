"""``make bench BENCH=control-fem`` times ``make control PRESET=fem``'s own MPC: the bench takes
``deapull control``'s flags and presets, and the Makefile passes it ``--preset fem``. Read off ``make -n`` (nothing
runs): the two targets' command lines give the same MPC settings, and the bench refuses what it
does not time before any step."""
from __future__ import annotations

import dataclasses
import importlib.util
import shlex
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def bench():
    spec = importlib.util.spec_from_file_location("bench_control_fem", ROOT / "bench" / "bench_control_fem.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def dry_run(target: str, *variables: str, program: str, first: str | None = None) -> list[str]:
    """The first command line of ``make -n TARGET`` that runs ``program`` (with ``first`` as its first
    argument, when given), as its arguments after it."""
    text = subprocess.run(["make", "-n", target, *variables], cwd=ROOT, check=True, capture_output=True,
                          text=True).stdout.replace("\\\n", " ")
    for line in text.splitlines():
        words = shlex.split(line)
        for i, w in enumerate(words):
            if w.endswith(program) and (first is None or words[i + 1:i + 2] == [first]):
                return words[i + 1 + (first is not None):]
    raise AssertionError(f"make -n {target}: no {program} line in\n{text}")


@pytest.mark.skipif(shutil.which("make") is None, reason="needs make")
def test_the_bench_runs_make_control_fems_mpc_on_the_plants_asked_for():
    """Broken once: the bench's recipe given its own stand-off 0 after the preset (the
    stand-off then differs: 0.0 against 2.0)."""
    mod = bench()
    timed = mod.config_of(dry_run("bench", "BENCH=control-fem", "FEM_PLANTS=C1,C3", program="bench_control_fem.py"))
    run = mod.config_of(dry_run("control", "PRESET=fem", program="deapull", first="control"))
    assert [p.name for p in timed.plants] == ["fem:C1", "fem:C3"]
    differ = {f.name: (getattr(timed, f.name), getattr(run, f.name)) for f in dataclasses.fields(timed)
              if getattr(timed, f.name) != getattr(run, f.name)}
    assert set(differ) == {"plants", "out"}, differ
    assert timed.mpc.standoff_stds == 2.0 and timed.mpc_phi == "prior" and timed.mpc.rate_V == 1.0   # the fem preset


@pytest.mark.parametrize("argv, named", [
    (["--policy", "mpc,pd", "--plant", "fem:C3"], "--policy mpc,pd"),
    (["--policy", "mpc", "--plant", "fem:C3,surrogate:C1"], "--plant surrogate:C1"),
    (["--policy", "mpc", "--plant", "fem:C9"], "unknown setup 'C9'"),
])
def test_the_bench_refuses_other_policies_and_plants_before_any_step(argv, named, tmp_path, capsys):
    assert bench().main([*argv, "--out", str(tmp_path / "b")]) == 2
    assert named in capsys.readouterr().err
    assert not (tmp_path / "b").exists()
