"""The ``catmip`` command line's argument types: each checks one value and raises with a message that
names the expected value (argparse adds the flag), so bad input stops before any work."""

from __future__ import annotations

import argparse
import json
import math
import os
from typing import Any

__all__ = [
    "Parser",
    "Formatter",
    "add_command",
    "add_allow_other_maps",
    "POSITIVE_INT",
    "NON_NEGATIVE_INT",
    "PROBABILITY",
    "CPUS",
    "UP_TO_CPUS",
    "checked",
    "check_comm",
    "check_method",
    "check_methods",
    "check_runs",
    "parse_set",
    "set_item",
    "USER_ERRORS",
    "number_type",
    "name_value",
    "pair_list",
    "explain",
    "missing_extra",
]

USER_ERRORS = (ValueError, OSError, ImportError)
"""What bad input raises (a bad value, path, or missing extra): one line and exit code 2."""

# the optional dependencies (pyproject's extras) by the module a command failed to import
_EXTRAS = {
    "rl": ("torch", "torchrl", "tensordict", "tensorboard", "tqdm"),
    "render": ("matplotlib", "imageio", "PIL"),
    "stats": ("scipy", "rliable", "arch", "pandas"),
    "distributed": ("ray",),
}


def missing_extra(module: str | None) -> str:
    """What to install for a command that failed to import ``module`` ('' for a module of no extra)."""
    top = (module or "").split(".")[0]
    for extra, modules in _EXTRAS.items():
        if top in modules:
            wheel = (
                "pip install torch==2.13.0 (the CPU wheel), then " if extra in ("rl", "distributed") else ""
            )
            return f"the {extra!r} extra: {wheel}pip install 'catmip[{extra}]' (or 'catmip[all]')"
    return ""


def explain(err: BaseException) -> str:
    """A user error's message, with the extra to install when it is a missing optional dependency."""
    what = str(err) or type(err).__name__
    extra = missing_extra(err.name) if isinstance(err, ModuleNotFoundError) else ""
    return f"{what}: this needs {extra}" if extra else what


def number_type(kind: type, low: float, below: float | None = None, bound: str = ""):
    """An argparse type: ``kind(text)``, finite, ``>= low``, ``< below``; ``bound`` words the range in
    messages instead."""
    bound = bound or f">= {low:g}" + ("" if below is None else f" and < {below:g}")
    noun = "an int" if kind is int else "a number"

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            value = None
        finite = value is not None and (kind is int or math.isfinite(value))  # huge ints: no float
        ok = finite and value >= low
        if not ok or (below is not None and value >= below):
            raise argparse.ArgumentTypeError(f"expected {noun} {bound}, got {text!r}")
        return value

    parse.__name__ = f"{noun} {bound}"
    return parse


POSITIVE_INT = number_type(int, 1)
NON_NEGATIVE_INT = number_type(int, 0)
PROBABILITY = number_type(float, 0, below=1)
CPUS = os.cpu_count() or 1
"""This machine's CPU count: flags that start threads or processes take at most this many."""
UP_TO_CPUS = number_type(int, 1, below=CPUS + 1, bound=f"from 1 to {CPUS} (this machine's CPU count)")


def name_value(text: str) -> tuple[str, str]:
    """An argparse type: ``NAME=VALUE`` as (name, value), both non-empty."""
    name, sep, value = text.partition("=")
    if not sep or not name.strip() or not value.strip():
        raise argparse.ArgumentTypeError(
            f"expected NAME=VALUE (a method's name, then its value), got {text!r}"
        )
    return name.strip(), value.strip()


def pair_list(text: str) -> list[tuple[str, str]]:
    """An argparse type: ``A:B,C:D`` as [(A, B), (C, D)] (method names; A - B is compared)."""
    pairs = []
    for item in (p.strip() for p in text.split(",") if p.strip()):
        a, sep, b = item.partition(":")
        if not sep or not a.strip() or not b.strip() or a.strip() == b.strip():
            raise argparse.ArgumentTypeError(f"expected pairs of two method names A:B[,C:D...], got {item!r}")
        pairs.append((a.strip(), b.strip()))
    if not pairs:
        raise argparse.ArgumentTypeError(f"expected pairs of two method names A:B[,C:D...], got {text!r}")
    return pairs


def checked(validate):
    """An argparse type: the text itself once ``validate(text)`` accepts it; its message otherwise."""

    def parse(text: str) -> str:
        try:
            validate(text)
        except USER_ERRORS as err:
            raise argparse.ArgumentTypeError(explain(err)) from None
        return text

    parse.__name__ = validate.__name__
    return parse


def check_comm(text: str) -> None:
    from catmip_rl.evaluation.evaluate import comm_sigma

    comm_sigma(text)


def check_method(text: str) -> None:
    from catmip_rl.evaluation.methods import parse_method

    parse_method(text)


def check_runs(text: str) -> None:
    from catmip_rl.evaluation.methods import parse_runs

    parse_runs(text)


def check_methods(text: str) -> None:
    specs = [spec for spec in text.split(",") if spec.strip()]
    if not specs:
        raise ValueError(f"expected a comma list of methods, got {text!r}")
    for spec in specs:
        check_method(spec)


def set_item(text: str) -> tuple[str, Any]:
    """``"field=value"`` -> ``(field, JSON value or the raw string)``."""
    key, sep, raw = text.partition("=")
    if not sep or not key.strip():
        raise argparse.ArgumentTypeError(f"expected FIELD=VALUE, got {text!r}")
    try:
        return key.strip(), json.loads(raw)
    except json.JSONDecodeError:
        return key.strip(), raw


def parse_set(items: list[str]) -> dict:
    """``["field=value", ...]`` -> ``{field: JSON value (or the raw string)}``; ValueError on an item
    without ``=``."""
    try:
        return dict(set_item(item) for item in items)
    except argparse.ArgumentTypeError as err:
        raise ValueError(f"--set {err}") from None


class Parser(argparse.ArgumentParser):
    """Errors as one line: ``catmip eval: error: argument --threads: expected an int >= 1, got '0'``."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")

    def parse_known_args(self, args=None, namespace=None):
        """Strict in every subcommand too: a flag that ``catmip bench perf`` does not take is refused by it,
        with its usage (argparse otherwise hands it to the top parser as an unknown argument)."""
        namespace, extras = super().parse_known_args(args, namespace)
        if extras:
            self.error(f"unrecognized arguments: {' '.join(extras)}")
        return namespace, extras


class Formatter(argparse.ArgumentDefaultsHelpFormatter):
    """Defaults shown where there is one (not for switches, nor flags that default to the preset's)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        default = action.default
        if default is None or default is False or default == [] or default is argparse.SUPPRESS:
            return action.help or ""
        return super()._get_help_string(action)


def add_command(sub, name: str, summary: str, description: str) -> argparse.ArgumentParser:
    """Subcommand ``name`` of ``sub`` (what ``add_subparsers`` returned): ``summary`` in its parent's list
    of commands, ``description`` atop its own ``--help``, its defaults shown (:class:`Formatter`)."""
    return sub.add_parser(name, help=summary, description=description, formatter_class=Formatter)


def add_allow_other_maps(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--allow-other-maps",
        action="store_true",
        help="evaluate even if this installation generates maps other than the frozen map sets' "
        "(catmip_env/maps/frozen_maps; the summary records it); without it such a run is refused",
    )
