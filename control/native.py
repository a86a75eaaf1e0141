"""The coin task's MPC compiled: f_a's step, its Jacobians and the box-iLQR in C.

An MPC step is 20 iterations of a 20-step plan: ~400 sequential steps of f_a plus 400
backward-pass steps. In eager torch each of them costs tens of microseconds of
per-operation overhead (the tip-contact step alone is a Newton loop of a dozen operations
per iteration), which is why the torch solver (:mod:`deapull.control.mpc` on
:class:`~deapull.control.dynamics.CoinDynamics`) needs ~0.8 s per MPC step. ``native_mpc.c``
runs the same arithmetic in C:

* the material network m of f-coulomb as the exact piecewise-affine function it is
  (:meth:`TipContactModel.material_pieces`: a binary search and one multiply-add per
  output instead of a 3 × 128 network);
* the coin's step by the same bracketed Newton iteration as
  :func:`~deapull.surrogate.models.tip_contact.tip_coin_step` (stopping per row), and its
  Jacobians from the implicit-function theorem at the root (what autograd through the
  torch model's final Newton correction gives);
* :func:`deapull.control.mpc.solve` for n = 3, m = 1, operation for operation.

``native_mpc_memory.c`` does the same for the tip-memory model f-memory, whose planning
state carries the tip's contact point and friction (ξ = (x, u, V, P, T), n = 5): its
four-output material network as pieces, the bracketed Newton solve of
:func:`~deapull.surrogate.models.memory.tip_memory_step` in T', its implicit-function
Jacobians, and the same iLQR for n = 5 (:class:`NativeMemoryDynamics`,
``tests/control/test_native_memory.py``). That iLQR (and the exported step and rollout around
each file's step) is written once, in ``ilqr_passes.h``, which both files include with their
own state width.

:class:`NativeCoinDynamics` (f-coulomb, and f-patch with its spread) is a drop-in
:class:`~deapull.control.dynamics.CoinDynamics` (``__call__``, ``jacobian`` for
:func:`mpc.linearize`, ``state``) with a :meth:`solve` returning the same
:class:`~deapull.control.mpc.Solution`. Tests hold its steps, Jacobians and plans to the
torch path's (``tests/control/test_native.py``). Compiled on first use like the surrogate's
native rollouts (same cache folder and flags, the cache keyed on ``ilqr_passes.h`` too);
without a compiler, or with ``DEAPULL_NATIVE=0``, :func:`available` is False and the torch
path is used.
"""
from __future__ import annotations

import ctypes
import functools
import logging
from pathlib import Path

import numpy as np
import torch

from deapull.control import mpc
from deapull.control.adapters import capabilities
from deapull.control.dynamics import U_UNIT_M_S, V_UNIT_V, X_UNIT_M, CoinDynamics
from deapull.surrogate import native as surrogate_native

log = logging.getLogger(__name__)

SOURCE = Path(__file__).with_name("native_mpc.c")
#: what both solvers include from this folder: the iLQR passes, shared
HEADERS = (Path(__file__).with_name("ilqr_passes.h"),)
_D = ctypes.POINTER(ctypes.c_double)


@functools.lru_cache(maxsize=1)
def library() -> ctypes.CDLL | None:
    """The compiled solver (compiled now if needed), or None where it cannot be had."""
    lib = surrogate_native.compiled(SOURCE, "native_mpc", "the MPC uses the slower torch path", HEADERS)
    if lib is None:
        return None
    _declare(lib, "deapull_coin")
    lib.deapull_coin_predict.argtypes = [ctypes.c_int] + [_D] * 12
    lib.deapull_coin_predict.restype = ctypes.c_int
    return lib


def _declare(lib: ctypes.CDLL, prefix: str) -> None:
    """Argument and return types of ``<prefix>_step``, ``_rollout`` and ``_ilqr``, whose
    signatures the f-coulomb and the f-memory solvers share (both are ``ilqr_passes.h``'s; only
    the state's width differs)."""
    common = [_D, ctypes.c_int, _D, _D, _D]
    getattr(lib, f"{prefix}_step").argtypes = common + [ctypes.c_int, _D, _D, _D, _D, _D]
    getattr(lib, f"{prefix}_rollout").argtypes = common + [ctypes.c_int, ctypes.c_int, _D, _D, _D]
    getattr(lib, f"{prefix}_ilqr").argtypes = common + [_D, _D, _D, _D, ctypes.c_int, ctypes.c_int, ctypes.c_int,
                                                        ctypes.c_int, ctypes.c_int, ctypes.c_int, _D,
                                                        ctypes.c_double, _D, _D, _D, _D, _D, _D, _D, _D]
    for name in ("step", "rollout", "ilqr"):
        getattr(lib, f"{prefix}_{name}").restype = ctypes.c_int


MEMORY_SOURCE = Path(__file__).with_name("native_mpc_memory.c")


@functools.lru_cache(maxsize=1)
def memory_library() -> ctypes.CDLL | None:
    """The compiled solver of the tip-memory f_a (``native_mpc_memory.c``), or None."""
    lib = surrogate_native.compiled(MEMORY_SOURCE, "native_mpc_memory", "the MPC uses the slower torch path",
                                    HEADERS)
    if lib is None:
        return None
    _declare(lib, "deapull_memory")
    lib.deapull_memory_predict.argtypes = [ctypes.c_int] + [_D] * 14
    lib.deapull_memory_scan.argtypes = [ctypes.c_int] + [_D] * 7 + [ctypes.c_double] * 2 + [_D] * 2
    for name in ("predict", "scan"):
        getattr(lib, f"deapull_memory_{name}").restype = ctypes.c_int
    return lib


def available(model=None) -> bool:
    """True when the library compiles and ``model`` (if given) is one it runs (f-coulomb, or
    f-memory: :class:`NativeMemoryDynamics`)."""
    if model is not None and "compiled_mpc_memory" in capabilities(model):
        return memory_library() is not None
    return (model is None or "compiled_mpc" in capabilities(model)) and library() is not None


def native_dynamics(model, phi, dt: float, dv_max_V: float, v_max_V: float) -> "NativeCoinDynamics":
    """The compiled twin of ``CoinDynamics(model, ...)`` for the kind of ``model``."""
    cls = NativeMemoryDynamics if "compiled_mpc_memory" in capabilities(model) else NativeCoinDynamics
    return cls(model, phi, dt, dv_max_V, v_max_V)


def _p(a: np.ndarray):
    return a.ctypes.data_as(_D)


def _np(t) -> np.ndarray:
    return np.ascontiguousarray(torch.as_tensor(t).detach().cpu().numpy(), dtype=np.float64)


class _NativeDynamics(CoinDynamics):
    """The compiled calls of a piecewise-linear f_a (step, Jacobians, rollout, box-iLQR), written
    once over the state size :attr:`n_state` and the library's export :attr:`prefix`
    (``control/ilqr_passes.h``); a subclass loads its library and its model's constants."""

    n_state: int
    prefix: str

    def _load_pieces(self) -> float:
        """The material network's pieces on [0, V_max] into the arrays the C code reads; returns
        its first output at V = 0 (the rest stroke)."""
        pieces = self._pieces = self.model.material_pieces(0.0, self.v_max_V)
        self._knots = np.ascontiguousarray(pieces["knots"], dtype=np.float64)
        self._slope = np.ascontiguousarray(pieces["slope"], dtype=np.float64)
        self._intercept = np.ascontiguousarray(pieces["intercept"], dtype=np.float64)
        t0 = (0.0 - pieces["mean"]) / pieces["scale"]
        k0 = int(np.clip(np.searchsorted(self._knots, t0, side="right") - 1, 0, len(self._slope) - 1))
        return self._slope[k0, 0] * t0 + self._intercept[k0, 0]

    def _fn(self, name: str):
        return getattr(self._lib, f"{self.prefix}_{name}")

    def _head(self):
        return (_p(self._params_now), len(self._slope), _p(self._knots), _p(self._slope), _p(self._intercept))

    def _call(self, xi, nu, jac: bool):
        n = self.n_state
        self._params_now = self._params()
        x = _np(xi).reshape(-1, n)
        v = _np(nu).reshape(-1)
        N = len(x)
        out = np.empty((N, n))
        A = np.empty((N, n, n)) if jac else None
        Bv = np.empty((N, n)) if jac else None
        self._fn("step")(*self._head(), N, _p(x), _p(v), _p(out), _p(A) if jac else None, _p(Bv) if jac else None)
        return out, A, Bv

    def __call__(self, xi: torch.Tensor, nu: torch.Tensor) -> torch.Tensor:
        return torch.from_numpy(self._call(xi, nu, False)[0])

    def jacobian(self, xi: torch.Tensor, nu: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """A = ∂ξ'/∂ξ (N, n, n) and B = ∂ξ'/∂ν (N, n, 1) (what :func:`mpc.linearize` uses)."""
        _, A, Bv = self._call(xi, nu, True)
        return torch.from_numpy(A), torch.from_numpy(Bv).unsqueeze(-1)

    def rollout(self, xi0: torch.Tensor, nu: torch.Tensor) -> torch.Tensor:
        """:func:`mpc.rollout` in one C call: ξ (B, T+1, n) from ξ0 (B, n) under ν (B, T, 1)."""
        n = self.n_state
        self._params_now = self._params()
        x0 = _np(xi0).reshape(-1, n)
        u = _np(nu).reshape(len(x0), -1)
        B, T = u.shape
        xs = np.empty((B, T + 1, n))
        self._fn("rollout")(*self._head(), B, T, _p(x0), _p(u), _p(xs))
        return torch.from_numpy(xs)

    def solve(self, cost: mpc.QuadCost, x0: torch.Tensor, u_init: torch.Tensor, lower=None, upper=None, *,
              iterations: int = 20, alphas=mpc.ALPHAS, tol: float = 0.0, mu0: float = 0.0) -> mpc.Solution:
        """:func:`mpc.solve` (same arguments, m = 1, a constant :class:`~mpc.QuadCost` on (ξ, ν)) in C."""
        n = self.n_state
        if not isinstance(cost, mpc.QuadCost) or cost.C.shape != (n + 1, n + 1) or cost.c.shape != (n + 1,):
            raise TypeError(f"the native solver takes a time-invariant QuadCost with C ({n + 1}, {n + 1}) and "
                            f"c ({n + 1},)")
        self._params_now = self._params()
        x0 = _np(x0).reshape(-1, n)
        B = len(x0)
        u = _np(u_init).reshape(B, -1).copy()
        T = u.shape[1]
        like = torch.zeros(B, T, 1, dtype=torch.float64)
        lo = _np(mpc._bounds(lower, like, -1.0)).reshape(B, T)
        hi = _np(mpc._bounds(upper, like, 1.0)).reshape(B, T)
        C, c = _np(cost.C), _np(cost.c)
        Cf = _np(cost.C_final) if cost.C_final is not None else np.zeros((n, n))
        cf = _np(cost.c_final) if cost.c_final is not None else np.zeros(n)
        steps = np.ascontiguousarray(alphas, dtype=np.float64)
        xs = np.empty((B, T + 1, n))
        J = np.empty(B)
        mu = np.full(B, float(mu0))
        history = np.zeros((B, iterations + 1))
        done = self._fn("ilqr")(
            *self._head(), _p(C), _p(c), _p(Cf), _p(cf), int(cost.C_final is not None), int(cost.c_final is not None),
            B, T, iterations, len(steps), _p(steps), float(tol), _p(x0), _p(u), _p(lo), _p(hi), _p(xs), _p(J),
            _p(mu), _p(history))
        if done < 0:
            raise MemoryError("the native MPC could not allocate its scratch memory")
        return mpc.Solution(x=torch.from_numpy(xs), u=torch.from_numpy(u).unsqueeze(-1), cost=torch.from_numpy(J),
                            history=torch.from_numpy(history[:, :done + 1]), mu=torch.from_numpy(mu),
                            iterations=done)


class NativeCoinDynamics(_NativeDynamics):
    """:class:`CoinDynamics` of an f-coulomb f_a evaluated in C (module docstring).

    Same constructor; :attr:`phi` may be replaced between calls. Rows of every call are
    independent. V must stay inside [0, ``v_max_V``] (the plan's clipping keeps it there).
    """

    n_state, prefix = 3, "deapull_coin"

    def __init__(self, model, phi, dt: float, dv_max_V: float, v_max_V: float):
        super().__init__(model, phi, dt, dv_max_V, v_max_V)
        if "compiled_mpc" not in capabilities(self.model) or library() is None:
            raise RuntimeError("the native coin MPC runs f-coulomb and f-patch models where a C compiler is available")
        rest = self._load_pieces()
        p = self._pieces
        if self._slope.shape[1] != self.model.material_outputs:
            raise RuntimeError(f"{self.model.kind}'s material network has {self.model.material_outputs} outputs, "
                               f"its pieces {self._slope.shape[1]}")
        self._static = [p["mean"], p["scale"], p["stroke_scale"], p["fy_mean"], p["fy_scale"], rest,
                        self._slope.shape[1], self.model.spread_shift]
        self._lib = library()

    def _params(self) -> np.ndarray:
        m = self.model
        phi = self.phi
        mean, scale, sx, fym, fys, rest, outputs, shift = self._static
        return np.array([mean, scale, sx, fym, fys, phi.value("mass_kg"), phi.value("mu_b"), phi.value("mu_t"),
                         m.gravity_m_s2, m.slip_rate_reg_m_s, self.dt, self.dv_max_V, self.v_max_V, m.iterations,
                         X_UNIT_M, U_UNIT_M_S, V_UNIT_V, rest, outputs, shift], dtype=np.float64)


class NativeMemoryDynamics(_NativeDynamics):
    """:class:`CoinDynamics` of an f-memory f_a (ξ = (x, u, V, P, T)) evaluated in C
    (``native_mpc_memory.c``): the same interface as :class:`NativeCoinDynamics`, n = 5."""

    n_state, prefix = 5, "deapull_memory"

    def __init__(self, model, phi, dt: float, dv_max_V: float, v_max_V: float):
        super().__init__(model, phi, dt, dv_max_V, v_max_V)
        if "compiled_mpc_memory" not in capabilities(self.model) or memory_library() is None or self.n != self.n_state:
            raise RuntimeError("the native memory MPC runs f-memory models where a C compiler is available")
        from deapull.surrogate.models.memory import COMPLIANCE_SCALE
        rest = self._load_pieces()
        if self._slope.shape[1] != 4:
            raise RuntimeError(f"f-memory's material network has 4 outputs, got {self._slope.shape[1]}")
        p = self._pieces
        self._static = [p["mean"], p["scale"], p["stroke_scale"], p["fy_mean"], p["fy_scale"], COMPLIANCE_SCALE, rest]
        self._lib = memory_library()

    def _params(self) -> np.ndarray:
        m, phi = self.model, self.phi
        mean, scale, sx, fym, fys, c0, rest = self._static
        pu, tu = (float(v) for v in self.memory_units)
        return np.array([mean, scale, sx, fym, fys, c0, phi.value("mass_kg"), phi.value("mu_b"), phi.value("mu_t"),
                         m.gravity_m_s2, m.slip_rate_reg_m_s, self.dt, self.dv_max_V, self.v_max_V, m.iterations,
                         X_UNIT_M, U_UNIT_M_S, V_UNIT_V, pu, tu, rest], dtype=np.float64)


def coin_predict(model, columns: dict, phi: dict, derivatives: bool = True):
    """The online inference's prediction for an f-coulomb or f-patch ``model`` in C
    (:class:`~deapull.control.inference.Predictor`'s ``predict`` and ``stick_shortfall``).

    Parameters
    ----------
    columns : dict
        The cached rows (``s``, ``a``, ``stroke_prev``, ``stroke``, ``fy``; f-patch's ``spread``).
    phi : dict
        ``mass_kg``, ``mu_b``, ``mu_t`` (floats: one coin for every row).
    derivatives : bool
        Also the derivatives with respect to log m_c, log μ_b, log μ_t.

    Returns
    -------
    (x̂ (n,), ∂x̂/∂log φ (n, 3) or None, shortfall (n,), ∂shortfall/∂log φ (n, 3) or None)
    """
    lib = library()
    s, a = columns["s"], columns["a"]
    rows = [_np(s[:, 0]), _np(s[:, 1]), _np(a[:, 1]), _np(columns["stroke_prev"]), _np(columns["stroke"]),
            _np(columns["fy"])]
    # ε per row for f-patch; None (NULL): ε_v for every row
    spread = columns.get("spread")
    rows.append(None if spread is None else
                _np(model.slip_eps((columns["stroke"] - columns["stroke_prev"]) / a[:, 1], spread)))
    return _predict(lib.deapull_coin_predict, rows, _phys(model, phi), derivatives)


def _phys(model, phi: dict) -> np.ndarray:
    return np.array([float(phi["mass_kg"]), float(phi["mu_b"]), float(phi["mu_t"]), model.gravity_m_s2,
                     model.slip_rate_reg_m_s, model.iterations], dtype=np.float64)


def _predict(fn, rows: list, phys: np.ndarray, derivatives: bool):
    """Call a compiled prediction (``deapull_coin_predict`` / ``deapull_memory_predict``) on the
    row columns ``rows`` and return its outputs as tensors (see :func:`coin_predict`)."""
    n = len(rows[0])
    pred, short = np.empty(n), np.empty(n)
    dpred = np.empty((n, 3)) if derivatives else None
    dshort = np.empty((n, 3)) if derivatives else None
    columns = (None if r is None else _p(r) for r in rows)     # None: NULL, the kernel's default
    fn(n, *columns, _p(phys), _p(pred), _p(dpred) if derivatives else None, _p(short),
       _p(dshort) if derivatives else None)
    as_t = (lambda v: None if v is None else torch.from_numpy(v))
    return as_t(pred), as_t(dpred), as_t(short), as_t(dshort)


def predictor(offered):
    """The compiled prediction of the online inference for a kind that offers the capabilities ``offered``
    (:func:`coin_predict` or :func:`memory_predict`), or None where the kind has none or no C
    compiler is at hand (``deapull control --set mpc.inference.engine=native`` checks this before loading)."""
    if "compiled_mpc_memory" in offered:
        return memory_predict if memory_library() is not None else None
    if "compiled_mpc" in offered:
        return coin_predict if library() is not None else None
    return None


def memory_predict(model, columns: dict, phi: dict, derivatives: bool = True):
    """:func:`coin_predict` for an f-memory ``model`` (``native_mpc_memory.c``): its cached rows
    (``s``, ``a``, ``memory`` = (P, T) before the step, ``stroke``, ``compliance``, ``fy0``,
    ``b`` at the step's voltage) through :func:`~deapull.surrogate.models.memory.tip_memory_step`
    with the memory given. Same returns as :func:`coin_predict`."""
    lib = memory_library()
    s, a, memory = columns["s"], columns["a"], columns["memory"]
    rows = [_np(s[:, 0]), _np(s[:, 1]), _np(a[:, 1]), _np(memory[:, 0]), _np(memory[:, 1]),
            *(_np(columns[k]) for k in ("stroke", "compliance", "fy0", "b"))]
    return _predict(lib.deapull_memory_predict, rows, _phys(model, phi), derivatives)


def memory_scan(model, columns: dict, phi: dict) -> torch.Tensor:
    """The memory (P, T) after each of consecutive rows, the first starting from its own
    ``memory`` entry and each next one from the row before's result (n, 2): the scan of
    :meth:`~deapull.control.adapters.TipMemoryAdapter.memory_along`, in C."""
    lib = memory_library()
    s, a = columns["s"], columns["a"]
    rows = [_np(s[:, 1]), _np(a[:, 1]), *(_np(columns[k]) for k in ("stroke", "compliance", "fy0", "b"))]
    n = len(rows[0])
    P0, T0 = (float(v) for v in columns["memory"][0])
    P, T = np.empty(n), np.empty(n)
    lib.deapull_memory_scan(n, *(_p(r) for r in rows), _p(_phys(model, phi)), P0, T0, _p(P), _p(T))
    return torch.from_numpy(np.stack([P, T], axis=-1))
