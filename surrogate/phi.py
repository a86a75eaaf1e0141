"""φ, the coin a physics model simulates, as a value passed to every step.

A :class:`Phi` holds the dynamics parameters of one coin (or one per batch row): its mass
m_c, the ground's Coulomb coefficient μ_b, the DEA tip's μ_t and the paper's threshold
voltage V^T. Each field is a float or a tensor (0-d for one coin, (N,) for one per row);
a field a model kind does not use may be NaN (or None). Models never store φ: it is an
argument of ``step``, ``forward`` and (through the batch) the training loss, so the same
model simulates any coin, a batch may mix coins, and gradients with respect to φ come from
autograd wherever its fields are tensors that require them.

Each model kind names the fields it needs (``Surrogate.phi_fields``) and refuses a φ
without them (``Surrogate.check_phi``); ``Surrogate.phi_of(data)`` builds the φ of a
dataset's coin, naming the file and the attribute when one is missing.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Sequence, Union

import torch

from deapull.errors import InputError

Value = Union[float, torch.Tensor, None]

#: field -> (unit, meaning, dataset attribute it is read from; None: derived from the run)
FIELDS = {
    "mass_kg": ("kg", "coin mass m_c", "coin_mass_kg"),
    "mu_b": ("1", "Coulomb friction coefficient coin-ground μ_b", "coin_mu_b"),
    "mu_t": ("1", "Coulomb friction coefficient DEA tip-coin μ_t", "coin_mu_t"),
    "v_threshold_V": ("V", "threshold voltage V^T of the paper's law", None),
}
#: fields that must be > 0 where used (the others >= 0)
POSITIVE = ("mass_kg", "v_threshold_V")


@dataclass(frozen=True)
class Phi:
    """The coin's parameters φ (SI units), floats or tensors.

    Attributes
    ----------
    mass_kg : float or torch.Tensor
        Coin mass m_c (kg).
    mu_b : float or torch.Tensor
        Ground–coin Coulomb coefficient μ_b.
    mu_t : float or torch.Tensor
        Tip–coin Coulomb coefficient μ_t (NaN where unknown or not needed).
    v_threshold_V : float or torch.Tensor
        The paper's threshold voltage V^T (V; NaN where not needed).
    """

    mass_kg: Value
    mu_b: Value
    mu_t: Value = math.nan
    v_threshold_V: Value = math.nan

    @classmethod
    def of(cls, data, v_threshold_V: float = math.nan) -> "Phi":
        """The φ of a dataset's coin (a :class:`deapull.surrogate.data.SetupData`): m_c, μ_b
        and μ_t (NaN when the file has none) from its attributes, V^T as given."""
        return cls(mass_kg=float(data.mass_kg), mu_b=float(data.mu_b), mu_t=float(data.mu_t),
                   v_threshold_V=float(v_threshold_V))

    @classmethod
    def rows(cls, phis: Sequence["Phi"], counts: Sequence[int], dtype: torch.dtype = torch.float32) -> "Phi":
        """One φ of (sum(counts),) tensors: ``phis[i]`` repeated ``counts[i]`` times."""
        counts_t = torch.as_tensor(list(counts))
        columns = {}
        for f in _NAMES:
            values = torch.tensor([_float(getattr(p, f)) for p in phis], dtype=dtype)
            columns[f] = torch.repeat_interleave(values, counts_t)
        return cls(**columns)

    def to(self, device: torch.device | str | None = None, dtype: torch.dtype | None = None) -> "Phi":
        """Every field as a tensor on ``device`` with ``dtype`` (floats become 0-d tensors;
        differentiable: gradients flow back to the original tensors)."""
        out = {}
        for f in _NAMES:
            v = getattr(self, f)
            if v is None:
                out[f] = None
            elif isinstance(v, torch.Tensor):
                out[f] = v.to(device=device, dtype=dtype or v.dtype)
            else:
                out[f] = torch.tensor(float(v), dtype=dtype or torch.get_default_dtype(), device=device)
        return Phi(**out)

    def __getitem__(self, index) -> "Phi":
        """The rows ``index`` of every per-row (≥ 1-d tensor) field; scalars are shared."""
        return Phi(**{f: (v[index] if isinstance(v, torch.Tensor) and v.dim() > 0 else v)
                      for f, v in self._items()})

    def __len__(self) -> int:
        sizes = {v.shape[0] for _, v in self._items() if isinstance(v, torch.Tensor) and v.dim() > 0}
        if len(sizes) > 1:
            raise ValueError(f"φ fields have different lengths {sorted(sizes)}")
        return sizes.pop() if sizes else 1

    def value(self, field: str) -> float:
        """Field ``field`` as one float (refused when it holds several values)."""
        v = getattr(self, field)
        if isinstance(v, torch.Tensor):
            if v.numel() != 1:
                raise ValueError(f"φ.{field} holds {v.numel()} values; one coin is needed here")
            return float(v.detach().reshape(()))
        return _float(v)

    def as_dict(self) -> dict:
        """Every field as a float (for records; one coin only)."""
        return {f: self.value(f) for f in _NAMES}

    def require(self, needed: Sequence[str], who: str) -> "Phi":
        """Refuse, naming the field, a φ whose ``needed`` fields are missing, non-finite or
        negative (m_c and V^T: not positive); returns ``self``."""
        for f in needed:
            unit, meaning, _ = FIELDS[f]
            v = getattr(self, f)
            bad = v is None
            if not bad:
                t = v.detach() if isinstance(v, torch.Tensor) else torch.tensor(float(v))
                bad = bool(not torch.isfinite(t).all() or (t < 0).any() or (f in POSITIVE and (t == 0).any()))
            if bad:
                allowed = "> 0" if f in POSITIVE else ">= 0"
                raise InputError(f"{who} needs φ.{f} ({meaning}, {unit}) finite and {allowed}, got {_show(v)}")
        return self

    def _items(self):
        return ((f, getattr(self, f)) for f in _NAMES)


_NAMES = tuple(f.name for f in fields(Phi))


def _float(v) -> float:
    return math.nan if v is None else float(v)


def _show(v) -> str:
    if isinstance(v, torch.Tensor):
        if v.numel() <= 4:
            return f"{v.detach().cpu().tolist()}"
        return f"a tensor of {v.numel()} values, some non-finite or out of range"
    return repr(v)
