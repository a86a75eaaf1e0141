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
import tempfile
from pathlib import Path

import numpy as np
import torch

from surrogate.models import LSTMBaseline, NNBaseline, PhysicsModel, Surrogate, TipContactModel

log = logging.getLogger(__name__)

SOURCE = Path(__file__).with_name("native_rollout.c")
# -march=native with vectorisable reductions, but no -ffast-math (it would set
# flush-to-zero for the whole process when the library is loaded)
FLAGS = ("-O3", "-march=native", "-fno-math-errno", "-fassociative-math", "-fno-signed-zeros",
         "-fno-trapping-math", "-ffp-contract=fast", "-shared", "-fPIC")
_DOUBLE_P = ctypes.POINTER(ctypes.c_double)
_FLOAT_P = ctypes.POINTER(ctypes.c_float)
_INT_P = ctypes.POINTER(ctypes.c_int)


def _cache_dir() -> Path:
    if os.environ.get("DEAPULL_CACHE_DIR"):
        return Path(os.environ["DEAPULL_CACHE_DIR"])
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "deapull"


@functools.lru_cache(maxsize=1)
def library() -> ctypes.CDLL | None:
    """The compiled kernels (compiled now if needed), or None where they cannot be had."""
    if os.environ.get("DEAPULL_NATIVE", "1") == "0":
        log.info("native rollouts disabled by DEAPULL_NATIVE=0; using torch")
        return None
    compiler = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if compiler is None or not SOURCE.is_file():
        log.warning("no C compiler (or %s missing): rollouts use the slower torch engine", SOURCE.name)
        return None
    key = hashlib.sha256("\0".join([SOURCE.read_text(), compiler, *FLAGS, platform.machine(),
                                    platform.node()]).encode()).hexdigest()[:16]
    target = _cache_dir() / f"native_rollout_{key}.so"
    if not target.is_file():
        try:
            _compile(compiler, target)
        except (OSError, subprocess.CalledProcessError) as err:
            detail = getattr(err, "stderr", "") or err
            log.warning("compiling %s failed (%s): rollouts use the slower torch engine", SOURCE.name, detail)
            return None
    lib = ctypes.CDLL(str(target))
    for kernel in (lib.deapull_rollout_physics, lib.deapull_rollout_tip):
        kernel.argtypes = [ctypes.c_int, _INT_P, _FLOAT_P, _DOUBLE_P, _DOUBLE_P, ctypes.c_int, _DOUBLE_P,
                           _DOUBLE_P, _DOUBLE_P, _DOUBLE_P]
    lib.deapull_rollout_nn.argtypes = [ctypes.c_int, _INT_P, _FLOAT_P, _DOUBLE_P, ctypes.c_int, _DOUBLE_P,
                                       _DOUBLE_P, _DOUBLE_P]
    lib.deapull_rollout_lstm.argtypes = [ctypes.c_int, ctypes.c_int, _FLOAT_P, _DOUBLE_P, ctypes.c_int, _DOUBLE_P,
                                         _DOUBLE_P, _DOUBLE_P]
    return lib


def _compile(compiler: str, target: Path) -> None:
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=target.parent, suffix=".so.tmp")
    os.close(fd)
    try:
        subprocess.run([compiler, *FLAGS, str(SOURCE), "-o", tmp, "-lm"], check=True, capture_output=True,
                       text=True, timeout=120)
        os.replace(tmp, target)
        log.info("compiled %s -> %s", SOURCE.name, target)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def supports(model: Surrogate) -> bool:
    """True when ``model`` has a native kernel and the kernels are available."""
    return isinstance(model, (PhysicsModel, TipContactModel, NNBaseline, LSTMBaseline)) and library() is not None


def _ptr(array: np.ndarray, kind):
    return array.ctypes.data_as(kind)


def _mlp_params(net: torch.nn.Sequential) -> tuple[np.ndarray, np.ndarray, int]:
    linears = [m for m in net if isinstance(m, torch.nn.Linear)]
    sizes = np.array([linears[0].in_features] + [m.out_features for m in linears], dtype=np.intc)
    flat = np.concatenate([t.detach().cpu().float().reshape(-1).numpy() for m in linears for t in (m.weight, m.bias)])
    return sizes, np.ascontiguousarray(flat, dtype=np.float32), len(linears)


def _buffers(model: Surrogate, *names: str) -> np.ndarray:
    return np.concatenate([getattr(model, n).detach().cpu().double().numpy() for n in names])


def rollout(model: Surrogate, s0: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """Roll ``model`` out from ``s0`` (2,) under ``actions`` (T, 2) in C.

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
    s0 = np.ascontiguousarray(s0, dtype=np.float64).reshape(2)
    actions = np.ascontiguousarray(actions, dtype=np.float64).reshape(-1, 2)
    n = len(actions)
    states = np.empty((n + 1, 2))
    forces = None
    if isinstance(model, PhysicsModel):
        sizes, params, n_layers = _mlp_params(model.material)
        norm = _buffers(model, "in_mean", "in_std", "z_mean", "z_std")
        phys = np.array([model.mass_kg.item(), model.mu_b.item(), model.gravity_m_s2, model.v_threshold_V.item(),
                         model.v_contact_loss_V])
        forces = np.empty((n, 2))
        rc = lib.deapull_rollout_physics(n_layers, _ptr(sizes, _INT_P), _ptr(params, _FLOAT_P), _ptr(norm, _DOUBLE_P),
                                         _ptr(phys, _DOUBLE_P), n, _ptr(s0, _DOUBLE_P), _ptr(actions, _DOUBLE_P),
                                         _ptr(states, _DOUBLE_P), _ptr(forces, _DOUBLE_P))
    elif isinstance(model, TipContactModel):
        sizes, params, n_layers = _mlp_params(model.material)
        norm = np.array([model.in_mean[2].item(), model.in_std[2].item(), model.s_std[0].item(),
                         model.z_mean[1].item(), model.z_std[1].item()])
        phys = np.array([model.mass_kg.item(), model.mu_b.item(), model.mu_t.item(), model.gravity_m_s2,
                         model.slip_rate_reg_m_s, model.iterations], dtype=np.float64)
        forces = np.empty((n, 2))
        rc = lib.deapull_rollout_tip(n_layers, _ptr(sizes, _INT_P), _ptr(params, _FLOAT_P), _ptr(norm, _DOUBLE_P),
                                     _ptr(phys, _DOUBLE_P), n, _ptr(s0, _DOUBLE_P), _ptr(actions, _DOUBLE_P),
                                     _ptr(states, _DOUBLE_P), _ptr(forces, _DOUBLE_P))
    elif isinstance(model, NNBaseline):
        sizes, params, n_layers = _mlp_params(model.net)
        norm = _buffers(model, "in_mean", "in_std", "ds_std")
        rc = lib.deapull_rollout_nn(n_layers, _ptr(sizes, _INT_P), _ptr(params, _FLOAT_P), _ptr(norm, _DOUBLE_P), n,
                                    _ptr(s0, _DOUBLE_P), _ptr(actions, _DOUBLE_P), _ptr(states, _DOUBLE_P))
    elif isinstance(model, LSTMBaseline):
        lstm = model.lstm
        params = np.concatenate([t.detach().cpu().float().reshape(-1).numpy() for t in (
            lstm.weight_ih_l0, lstm.weight_hh_l0, lstm.bias_ih_l0, lstm.bias_hh_l0, model.head.weight,
            model.head.bias)]).astype(np.float32)
        norm = _buffers(model, "in_mean", "in_std", "ds_std")
        rc = lib.deapull_rollout_lstm(lstm.hidden_size, model.window, _ptr(params, _FLOAT_P), _ptr(norm, _DOUBLE_P),
                                      n, _ptr(s0, _DOUBLE_P), _ptr(actions, _DOUBLE_P), _ptr(states, _DOUBLE_P))
    else:
        raise TypeError(f"no native kernel for {type(model).__name__}")
    if rc != 0:
        raise MemoryError("native rollout could not allocate its scratch memory")
    return states, forces
