"""The native rollout engine: batch-1 CPU rollouts in compiled C, called through ctypes.

A 1 s rollout is ~1000 sequential steps of a 3×128 hidden-layer network; in torch each step
costs tens of microseconds of per-operation overhead, far above its ~35k multiply-adds.
``native_rollout.c`` runs the same arithmetic in one C loop. It is compiled on first use
with the system C compiler (the one FFCx already needs for the FEM stage) into
``$DEAPULL_CACHE_DIR`` (default ``~/.cache/deapull``), keyed by the source, the flags and
the machine. Without a compiler, or with ``DEAPULL_NATIVE=0``, :func:`library` returns
None and rollouts use the torch engine.
"""
from __future__ import annotations

import ctypes
import functools
import hashlib
import logging
import os
import platform
import shutil
import subprocess
from pathlib import Path

import numpy as np

from deapull.io import atomic_write

log = logging.getLogger(__name__)

SOURCE = Path(__file__).with_name("native_rollout.c")
#: the headers every kernel may include (this folder is on the include path): the coin's step
HEADERS = (Path(__file__).with_name("coin_step.h"),)
# -march=native with vectorisable reductions, but no -ffast-math (it would set
# flush-to-zero for the whole process when the library is loaded)
FLAGS = ("-O3", "-march=native", "-fno-math-errno", "-fassociative-math", "-fno-signed-zeros",
         "-fno-trapping-math", "-ffp-contract=fast", "-shared", "-fPIC")
_DOUBLE_P = ctypes.POINTER(ctypes.c_double)
_POINTERS = {np.dtype(np.float64): _DOUBLE_P, np.dtype(np.float32): ctypes.POINTER(ctypes.c_float),
             np.dtype(np.intc): ctypes.POINTER(ctypes.c_int)}


def _cache_dir() -> Path:
    if os.environ.get("DEAPULL_CACHE_DIR"):
        return Path(os.environ["DEAPULL_CACHE_DIR"])
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "deapull"


def compiled(source: Path, stem: str, fallback: str, headers: tuple[Path, ...] = ()) -> ctypes.CDLL | None:
    """``source`` compiled with :data:`FLAGS` into the cache (once per source, compiler and
    machine) and loaded, or None — with ``DEAPULL_NATIVE=0``, without a C compiler or when
    the compiler fails; ``fallback`` says in the log what is used instead. Shared by every
    C kernel of the project (this module's rollouts, the MPC's ``control/native.py``).

    ``headers``: the files ``source`` includes from its own folder (``#include "..."`` finds
    them there, so they need no include path); keyed with :data:`HEADERS`, so that an edit
    to one compiles anew instead of loading a stale library."""
    if os.environ.get("DEAPULL_NATIVE", "1") == "0":
        log.info("%s disabled by DEAPULL_NATIVE=0; %s", source.name, fallback)
        return None
    compiler = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    missing = [f.name for f in (source, *HEADERS, *headers) if not f.is_file()]
    if compiler is None or missing:
        log.warning("no C compiler (or %s missing): %s", ", ".join(missing) or source.name, fallback)
        return None
    key = hashlib.sha256("\0".join([source.read_text(), *(h.read_text() for h in (*HEADERS, *headers)), compiler,
                                    *FLAGS, platform.machine(), platform.node()]).encode()).hexdigest()[:16]
    target = _cache_dir() / f"{stem}_{key}.so"
    if not target.is_file():
        try:
            atomic_write(target, lambda tmp: subprocess.run([compiler, *FLAGS, f"-I{HEADERS[0].parent}", str(source),
                                                             "-o", tmp, "-lm"],
                                                            check=True, capture_output=True, text=True, timeout=120))
        except (OSError, subprocess.CalledProcessError) as err:
            log.warning("compiling %s failed (%s): %s", source.name, getattr(err, "stderr", "") or err, fallback)
            return None
    return ctypes.CDLL(str(target))


@functools.lru_cache(maxsize=1)
def library() -> ctypes.CDLL | None:
    """The compiled kernels (compiled now if needed), or None where they cannot be had."""
    return compiled(SOURCE, "native_rollout", "rollouts use the slower torch engine")


def supports(model) -> bool:
    """True when ``model``'s kind has a native kernel and the kernels are available."""
    return callable(getattr(model, "native_kernel", None)) and library() is not None


def _argument(value):
    """A kernel argument as ctypes wants it: (argtype, value)."""
    if isinstance(value, (bool, np.bool_)):
        raise TypeError("a native kernel takes no booleans")
    if isinstance(value, (int, np.integer)):
        return ctypes.c_int, int(value)
    if isinstance(value, np.ndarray) and value.dtype in _POINTERS and value.flags.c_contiguous:
        kind = _POINTERS[value.dtype]
        return kind, value.ctypes.data_as(kind)
    raise TypeError(f"a native kernel takes ints and C-contiguous float32/float64/int arrays, not {value!r:.80}")


def rollout(model, phi, s0: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """Roll ``model`` out from ``s0`` (2,) under ``actions`` (T, 2) in C, for the coin ``phi``.

    The model names its kernel and hands over its parameters
    (``model.native_kernel(phi)``, a :class:`~deapull.surrogate.models.base.NativeKernel`);
    this function only loads the library and calls it.

    Returns
    -------
    states : numpy.ndarray
        (T + 1, 2) float64, starting with ``s0``.
    forces : numpy.ndarray or None
        (T, 2) float64 for f = d∘m, None for the black boxes.
    """
    lib = library()
    if lib is None:
        raise RuntimeError("the native rollout engine is not available")
    if not callable(getattr(model, "native_kernel", None)):
        raise TypeError(f"no native kernel for {type(model).__name__}")
    kernel = model.native_kernel(phi)
    s0 = np.ascontiguousarray(s0, dtype=np.float64).reshape(2)
    actions = np.ascontiguousarray(actions, dtype=np.float64).reshape(-1, 2)
    n = len(actions)
    states = np.empty((n + 1, 2))
    forces = np.empty((n, 2)) if kernel.forces else None
    outputs = (n, s0, actions, states) + ((forces,) if kernel.forces else ())
    arguments = [_argument(v) for v in (*kernel.args, *outputs)]
    function = getattr(lib, kernel.name)
    function.argtypes = [t for t, _ in arguments]
    function.restype = ctypes.c_int
    if function(*(v for _, v in arguments)) != 0:
        raise MemoryError("native rollout could not allocate its scratch memory")
    return states, forces
