"""Voltage protocols V(t): what the scene's ``[load]`` section asks the FEM to play.

``load.protocol`` picks one; each takes only the keys it needs (the scene schema refuses
the others, naming them), every voltage lies in [0, ``load.voltage_max_V``] and every time
is finite and increasing:

=================  =========================================================================
``ramp``           0 → V_max over ``ramp_time_s``, then held (the paper's protocol)
``ramp_hold_ramp`` 0 → V_max over ``ramp_time_s``, held ``hold_time_s``, then → ``voltage_end_V``
                   over ``ramp_down_time_s``, then held
``release``        starts actuated at V_max (the DEA is placed on the coin at V_max), → 0 over
                   ``ramp_time_s``, then held at 0
``triangle``       0 → V_max over ``ramp_time_s`` and back to 0 over the next ``ramp_time_s``,
                   repeated
``sine``           V_max (1 − cos(2π t / ``period_s``)) / 2: starts at 0 with zero slope
``table``          piecewise linear through (``table_t_s``, ``table_V``) given inline, or read
                   from ``table_csv`` (two columns t_s, V; a header line is allowed); held after
                   the last point; the first time must be 0
``random``         seeded (``seed``) piecewise linear from 0 V: segments of duration uniform in
                   [``segment_min_s``, ``segment_max_s``] with slopes uniform in
                   [−``rate_max_V_s``, ``rate_max_V_s``] (100–4000 V/s), each cut where it reaches 0
                   or V_max
=================  =========================================================================

A :class:`Protocol` is a value: ``voltage(t)`` and the ``kinks`` (times where dV/dt jumps), so
that a time stepper can land on them. The FEM (:meth:`deapull.fem_solver.stepping.Stepper.run`)
plays it; a controller instead calls ``advance(V, dt)`` with voltages of its own.
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from deapull.errors import InputError

#: keys of ``[load]`` that every protocol takes
COMMON = ("protocol", "voltage_max_V", "end_time_s")
#: the further keys of ``[load]`` each protocol takes (``table``: inline or from a CSV file)
KEYS = {
    "ramp": ("ramp_time_s",),
    "ramp_hold_ramp": ("ramp_time_s", "hold_time_s", "voltage_end_V", "ramp_down_time_s"),
    "release": ("ramp_time_s",),
    "triangle": ("ramp_time_s",),
    "sine": ("period_s",),
    "table": ("table_t_s", "table_V", "table_csv"),
    "random": ("seed", "rate_max_V_s", "segment_min_s", "segment_max_s"),
}
NAMES = tuple(KEYS)
#: allowed range of ``rate_max_V_s`` (V/s)
RATE_RANGE = (100.0, 4000.0)


class ProtocolError(InputError):
    """A protocol that cannot be played; the message names the key, the value and what is allowed."""


@dataclass(frozen=True)
class Protocol:
    """V(t) of one scene: a name, the knots of a piecewise-linear V (or None for ``sine``).

    Attributes
    ----------
    name : str
    voltage_max_V : float
    end_time_s : float
    knots_t, knots_V : tuple of float
        Piecewise-linear V(t) through these points, held after the last (empty for sine).
    period_s : float
        Period of ``sine`` (NaN for the others).
    """

    name: str
    voltage_max_V: float
    end_time_s: float
    knots_t: tuple = ()
    knots_V: tuple = ()
    period_s: float = math.nan

    def voltage(self, t: float) -> float:
        """V at time ``t`` (s)."""
        if self.name == "sine":
            return self.voltage_max_V * 0.5 * (1.0 - math.cos(2.0 * math.pi * t / self.period_s))
        if self.name == "ramp":   # kept in this exact form: the shipped datasets were made with it
            return self.voltage_max_V * min(t / self.knots_t[1], 1.0)
        return float(np.interp(t, self.knots_t, self.knots_V))

    __call__ = voltage

    def kinks(self) -> np.ndarray:
        """Times in (0, end) where dV/dt jumps (the inner knots)."""
        t = np.asarray(self.knots_t, dtype=float)
        return t[(t > 0) & (t < self.end_time_s)]

    def sample(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """(t, V) on a uniform grid of step ``dt`` over [0, end] (the end included)."""
        n = max(int(math.ceil(self.end_time_s / dt - 1e-9)), 1)
        t = np.minimum(np.arange(n + 1) * dt, self.end_time_s)
        return t, np.array([self.voltage(ti) for ti in t])

    def max_rate(self) -> float:
        """Largest |dV/dt| (V/s)."""
        if self.name == "sine":
            return math.pi * self.voltage_max_V / self.period_s
        dt, dv = np.diff(self.knots_t), np.diff(self.knots_V)
        keep = dt > 0
        return float(np.max(np.abs(dv[keep] / dt[keep]), initial=0.0))


def from_load(load) -> Protocol:
    """The :class:`Protocol` of a validated ``[load]`` section (a :class:`deapull.scene.Load`)."""
    vmax, end, name = load.voltage_max_V, load.end_time_s, load.protocol
    if name == "ramp":
        t, V = [0.0, load.ramp_time_s], [0.0, vmax]
    elif name == "release":
        t, V = [0.0, load.ramp_time_s], [vmax, 0.0]
    elif name == "ramp_hold_ramp":
        t1 = load.ramp_time_s
        t2 = t1 + load.hold_time_s
        t = [0.0, t1, t2, t2 + load.ramp_down_time_s]
        V = [0.0, vmax, vmax, load.voltage_end_V]
    elif name == "triangle":
        n = int(math.ceil(end / load.ramp_time_s)) + 1
        t = [k * load.ramp_time_s for k in range(n + 1)]
        V = [0.0 if k % 2 == 0 else vmax for k in range(n + 1)]
    elif name == "sine":
        return Protocol(name, vmax, end, period_s=load.period_s)
    elif name == "table":
        t, V = list(load.table_t_s), list(load.table_V)
    elif name == "random":
        t, V = random_knots(load.seed, vmax, end, load.rate_max_V_s, load.segment_min_s, load.segment_max_s)
    else:
        raise ProtocolError(f"load.protocol = {name!r}: expected one of {', '.join(NAMES)}")
    return Protocol(name, vmax, end, tuple(float(x) for x in t), tuple(float(v) for v in V))


def random_knots(seed: int, vmax: float, end: float, rate_max: float, seg_min: float, seg_max: float):
    """Knots of the seeded random protocol (see the module's table); reproducible for a seed."""
    rng = np.random.default_rng(seed)
    t, V = [0.0], [0.0]
    while t[-1] < end:
        duration = rng.uniform(seg_min, seg_max)
        slope = rng.uniform(-rate_max, rate_max)
        if (V[-1] <= 0.0 and slope < 0) or (V[-1] >= vmax and slope > 0):
            slope = -slope                    # at a bound: turn back into the range
        v = V[-1] + slope * duration
        if v > vmax or v < 0.0:           # cut the segment where it reaches a bound
            bound = vmax if v > vmax else 0.0
            duration = (bound - V[-1]) / slope
            v = bound
        t.append(t[-1] + duration)
        V.append(v)
    return t, V


def read_table_csv(path: str | Path, key: str = "load.table_csv") -> tuple[list[float], list[float]]:
    """Two columns (t in s, V in V) of a CSV file; a first line that is not numbers is a header."""
    path = Path(path)
    if not path.is_file():
        raise ProtocolError(f"{key} = {str(path)!r}: no such file")
    t, V = [], []
    with path.open(newline="") as fh:
        for i, row in enumerate(csv.reader(fh)):
            if not row or all(not c.strip() for c in row):
                continue
            try:
                a, b = (float(c) for c in row[:2])
            except ValueError:
                if i == 0:
                    continue          # a header
                raise ProtocolError(f"{key} = {str(path)!r}: line {i + 1} {row!r} is not two numbers") from None
            if len(row) < 2:
                raise ProtocolError(f"{key} = {str(path)!r}: line {i + 1} has fewer than two columns")
            t.append(a)
            V.append(b)
    return t, V


def check_table(t, V, vmax: float, key: str = "load.table") -> None:
    """Times finite, starting at 0 and strictly increasing; voltages finite and in [0, V_max]."""
    if len(t) != len(V) or len(t) < 2:
        raise ProtocolError(f"{key}_t_s / {key}_V: need two lists of the same length >= 2, got {len(t)} and {len(V)}")
    t, V = np.asarray(t, dtype=float), np.asarray(V, dtype=float)
    if not np.all(np.isfinite(t)):
        raise ProtocolError(f"{key}_t_s = {t.tolist()}: every time must be finite")
    if t[0] != 0.0 or np.any(np.diff(t) <= 0):
        raise ProtocolError(f"{key}_t_s = {t.tolist()}: must start at 0 and increase strictly")
    bad = ~np.isfinite(V) | (V < 0) | (V > vmax)
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        raise ProtocolError(f"{key}_V[{i}] = {float(V[i])!r}: expected a finite voltage in [0, load.voltage_max_V = {vmax:g}]")
