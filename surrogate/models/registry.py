"""The registry of model kinds: name → :class:`~deapull.surrogate.models.base.Surrogate` class.

A kind's module registers its class with :func:`register`; :func:`build` makes one by
name. Nothing else dispatches on kind names: what differs between kinds (φ, the
hyper-parameters of a training run, the native kernel) is asked of the class.
"""
from __future__ import annotations

from deapull.surrogate.models.base import InputRange, Normalisation, Surrogate

#: the registered kinds, in registration order (the order the CLI and the tables list them)
KINDS: dict[str, type[Surrogate]] = {}


def register(cls: type[Surrogate]) -> type[Surrogate]:
    """Class decorator: make ``cls`` buildable under ``cls.kind``."""
    if not cls.kind:
        raise ValueError(f"{cls.__name__} has no kind name")
    if cls.kind in KINDS and KINDS[cls.kind] is not cls:
        raise ValueError(f"model kind {cls.kind!r} is registered twice ({KINDS[cls.kind].__name__}, {cls.__name__})")
    KINDS[cls.kind] = cls
    return cls


def kind_class(kind: str) -> type[Surrogate]:
    """The class of ``kind``; a ValueError lists the known kinds."""
    try:
        return KINDS[kind]
    except KeyError:
        raise ValueError(f"unknown model kind {kind!r}; choose one of {', '.join(KINDS)}") from None


def build(kind: str, norm: Normalisation, input_range: InputRange, hparams: dict | None = None) -> Surrogate:
    """A fresh model of ``kind`` (one of :data:`KINDS`) with hyper-parameters ``hparams``."""
    return kind_class(kind)(norm, input_range, **dict(hparams or {}))
