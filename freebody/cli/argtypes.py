"""argparse value types shared by the subcommands: each rejects bad values with one line (exit 2)."""
from __future__ import annotations

import argparse
import math
from typing import Callable


def number(minimum: float = -math.inf, strict: bool = False) -> Callable[[str], float]:
    """A finite float >= minimum (> minimum when ``strict``)."""
    sign = ">" if strict else ">="

    def parse(text: str) -> float:
        try:
            x = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        if not math.isfinite(x) or x < minimum or (strict and x == minimum):
            raise argparse.ArgumentTypeError(f"must be a finite number {sign} {minimum:g}, got {text!r}")
        return x

    return parse


def integer(minimum: int = 0, maximum: int | None = None) -> Callable[[str], int]:
    """An integer in [minimum, maximum]."""
    def parse(text: str) -> int:
        try:
            n = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
        if n < minimum or (maximum is not None and n > maximum):
            span = f"from {minimum} to {maximum}" if maximum is not None else f">= {minimum}"
            raise argparse.ArgumentTypeError(f"must be an integer {span}, got {text!r}")
        return n

    return parse


positive_float = number(0.0, strict=True)
nonnegative_float = number(0.0)
positive_int = integer(1)
nonnegative_int = integer(0)
