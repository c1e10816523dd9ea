"""The configs' common ground: value checks that name the parameter, and ``from_dict`` /
``to_dict`` with unknown-key rejection (core/config.py, core/texture/config.py)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any, TypeVar

_T = TypeVar("_T", bound="_ConfigBase")


def _check_finite(name: str, value: Any) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number, got {value!r}")


def _check_nonneg(name: str, value: Any) -> None:
    _check_finite(name, value)
    if value < 0:
        raise ValueError(f"{name} must be >= 0, got {value!r}")


def _check_pos(name: str, value: Any) -> None:
    _check_finite(name, value)
    if value <= 0:
        raise ValueError(f"{name} must be > 0, got {value!r}")


def _check_unit(name: str, value: Any) -> None:
    if not 0.0 <= value <= 1.0:
        raise ValueError(f"{name} must be in [0, 1], got {value!r}")


def _check_int(name: str, value: Any, minimum: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{name} must be an int, got {value!r}")
    if value < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {value!r}")


class _ConfigBase:
    """Mixin: ``from_dict`` with unknown-key rejection."""

    @classmethod
    def from_dict(cls: type[_T], d: Mapping[str, Any]) -> _T:
        """Build the config from a mapping; unknown keys raise ``ValueError`` naming them.

        Parameters
        ----------
        d : Mapping[str, Any]
            Parameter name -> value. Missing keys keep their defaults.

        Returns
        -------
        config
            A validated instance.
        """
        names = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
        unknown = sorted(set(d) - names)
        if unknown:
            raise ValueError(f"{cls.__name__}: unknown parameter(s) {unknown}; known: {sorted(names)}")
        return cls(**dict(d))  # type: ignore[call-arg]

    def to_dict(self) -> dict[str, Any]:
        """Return the parameters as a plain dict (inverse of :meth:`from_dict`)."""
        return dataclasses.asdict(self)  # type: ignore[call-overload]
