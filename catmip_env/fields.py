"""One validator for the fields of the configs (``EnvConfig``, ``TrainConfig``, ``RobotClass``): each
field has a :class:`Rule` (its type, and the range or values it takes), and :func:`check` raises a
ValueError that names the field, the rule and the value: ``EnvConfig.map_size must be an int in
[10, 512], got 8``. A value of the wrong type is named as such, never met later as a TypeError (values
come from JSON: ``--set``, config files)."""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["Rule", "check", "is_int", "is_number", "is_bool", "is_str", "INT", "NUMBER", "BOOL", "STR"]


def is_int(v: Any) -> bool:
    """An int, never a bool (JSON's true is not 1 here)."""
    return isinstance(v, int) and not isinstance(v, bool)


def is_number(v: Any) -> bool:
    """A finite real number (ints too; not a bool)."""
    return isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v)


def is_bool(v: Any) -> bool:
    return isinstance(v, (bool, np.bool_))


def is_str(v: Any) -> bool:
    return isinstance(v, str)


@dataclass(frozen=True)
class Rule:
    """A field's type (``noun`` in messages, ``is_type`` the test) and optionally its range or values
    (``bound`` in messages, ``within`` the test, applied once the type holds)."""

    noun: str
    is_type: Callable[[Any], bool]
    bound: str = ""
    within: Callable[[Any], bool] | None = None

    def __call__(self, bound: str, within: Callable[[Any], bool]) -> Rule:
        """This type with a range: ``INT(">= 1", lambda v: v >= 1)``."""
        return Rule(self.noun, self.is_type, bound, within)


INT = Rule("an int", is_int)
NUMBER = Rule("a finite number", is_number)
BOOL = Rule("true or false", is_bool)
STR = Rule("a string", is_str)


def check(owner: str, name: str, value: Any, rule: Rule) -> None:
    """A ValueError "``owner``.``name`` must be <noun> <bound>, got <value>" unless ``value`` satisfies
    ``rule``."""
    if not rule.is_type(value) or (rule.within is not None and not rule.within(value)):
        wanted = f"{rule.noun} {rule.bound}" if rule.bound else rule.noun
        raise ValueError(f"{owner}.{name} must be {wanted}, got {value!r}")
