"""Value parsers of the ``play`` and ``experiment`` flags, shared by both commands.

argparse calls them on a flag's text; a bad value raises
``argparse.ArgumentTypeError``, which argparse prints as ``argument --flag: must be
..., got '...'`` (exit code 2). Only the standard library is imported here, so that
``--help`` stays light.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

__all__ = ["number", "parse_dead_zone", "parse_range", "whole_number"]


def number(flag: str, allowed: str, check: Callable[[float], bool]) -> Callable[[str], float]:
    """A parser of ``flag``'s value: a finite float for which ``check`` holds.

    ``allowed`` says what is allowed in the error (``"a number > 0"``).
    """

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {allowed}, got {text!r}") from None
        if not (math.isfinite(value) and check(value)):
            raise argparse.ArgumentTypeError(f"must be {allowed}, got {text!r}")
        return value

    parse.__name__ = flag
    return parse


def whole_number(text: str) -> int:
    """A flag's value as a whole number >= 0 (a realisation, an axis, a row)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a whole number >= 0, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be a whole number >= 0, got {text!r}")
    return value


#: ``--dead-zone`` of both commands: the share of full deflection read as zero.
parse_dead_zone = number("--dead-zone", "a number in [0, 1)", lambda v: 0.0 <= v < 1.0)
#: ``--range`` of both commands: the raw reading (pixels, axis value) of full deflection.
parse_range = number("--range", "a number > 0", lambda v: v > 0.0)
