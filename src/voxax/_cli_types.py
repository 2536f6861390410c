"""The command line's option types: each check of a value gives one clear line."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable


def integer(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None


def number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def resolution(multiple: int = 1, least: int = 1) -> Callable[[str], int]:
    least = max(least, multiple)

    def check(text: str) -> int:
        n = integer(text)
        if n < least:
            raise argparse.ArgumentTypeError(f"the resolution must be at least {least}, got {n}")
        if n % multiple:
            raise argparse.ArgumentTypeError(f"the resolution must be a multiple of {multiple}, got {n}")
        return n

    check.__name__ = "resolution"
    return check


def at_least(least: int) -> Callable[[str], int]:
    def check(text: str) -> int:
        n = integer(text)
        if n < least:
            raise argparse.ArgumentTypeError(f"expected an integer >= {least}, got {n}")
        return n

    check.__name__ = "count"
    return check


def positive(text: str) -> float:
    value = number(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text}")
    return value


def non_negative(text: str) -> float:
    value = number(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text}")
    return value
