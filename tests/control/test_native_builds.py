"""Where a C compiler is found, every compiled kernel builds.

The native tests skip when their library is None, so a kernel source that stops compiling would
otherwise show up only as skips (the nineteenth session met this: ``native_mpc.c`` without
``<stddef.h>`` turned tests/control/test_native.py into 11 skips). Broken once that way (the
include removed): ``native_mpc.c``'s case failed."""
from __future__ import annotations

import os
import shutil

import pytest

from deapull.control import native as control_native
from deapull.surrogate import native as surrogate_native

COMPILER = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")


@pytest.mark.skipif(COMPILER is None or os.environ.get("DEAPULL_NATIVE", "1") == "0",
                    reason="no C compiler, or DEAPULL_NATIVE=0: the torch paths are used")
@pytest.mark.parametrize("source, load", [("surrogate/native_rollout.c", surrogate_native.library),
                                          ("control/native_mpc.c", control_native.library),
                                          ("control/native_mpc_memory.c", control_native.memory_library)])
def test_every_kernel_builds_where_a_compiler_is_found(source, load):
    assert load() is not None, f"{source} did not build with {COMPILER} (the log says why)"
