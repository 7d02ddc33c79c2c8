"""Request arguments checked, and the refusal a handler raises: shared by the loop's command
handling (:mod:`daemon.loop.commands`) and the planner beside it (:mod:`daemon.planner.commands`).

Every refusal carries a protocol error code, a message in plain words and, where a client
may want to act on it without parsing English, ``data``: a map naming the argument and the
numbers (docs/protocol.md, "Error data").
"""
from __future__ import annotations

import math

from daemon.wire import protocol as P


class CommandFailed(Exception):
    def __init__(self, code: str, message: str, data: dict | None = None):
        super().__init__(message)
        self.code, self.message, self.data = code, message, data

    def __reduce__(self):  # it crosses from the planner process to the loop's
        return type(self), (self.code, self.message, self.data)


LARGEST_FIXED = 1e6  # beyond this a refusal shows a number in 3 significant digits, not its 300 integer digits


def number_text(value: float, digits: int = 2) -> str:
    """``value`` as a refusal shows it: ``digits`` after the point, or, beyond ``LARGEST_FIXED``
    (a mistyped 1e308), 3 significant digits."""
    return f"{value:.{digits}f}" if abs(value) < LARGEST_FIXED else f"{value:.3g}"


def bad_args(message: str, argument: str, **data) -> CommandFailed:
    """A ``bad_args`` refusal; its data names the request's ``argument`` (a top-level name)
    and, for one element of a list, its ``index`` (a list of 0-based indices, outermost
    first), with any bounds (``low``, ``high``) or choices (``allowed``)."""
    return CommandFailed(P.BAD_ARGS, message, {"argument": argument, **data})


def number(args: dict, key: str, low: float, high: float, default: float | None = None) -> float:
    return checked_number(key, args.get(key, default), low, high)


def checked_number(key: str, value, low: float, high: float, index: int | None = None) -> float:
    """``value`` as a float in low..high, or a bad_args error naming ``key`` (element
    ``index`` of it, when given)."""
    where = {} if index is None else {"index": [index]}
    label = key if index is None else f"{key}[{index}]"
    if value is None:
        raise bad_args(f"'{label}' is required", key, **where)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise bad_args(f"'{label}' must be a finite number, got {value!r:.80}", key, **where)
    if not low <= value <= high:
        raise bad_args(f"'{label}' = {value} is outside {low}..{high}", key, low=low, high=high, **where)
    return float(value)


def integer(args: dict, key: str, low: int, high: int, default: int) -> int:
    value = args.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int):
        raise bad_args(f"'{key}' must be a whole number, got {value!r:.80}", key)
    if not low <= value <= high:
        raise bad_args(f"'{key}' = {value} is outside {low}..{high}", key, low=low, high=high)
    return value


def numbers(args: dict, key: str, n: int) -> list[float]:
    return checked_numbers(key, args.get(key), n)


def checked_numbers(key: str, value, n: int, index: int | None = None) -> list[float]:
    """``value`` as a list of n finite floats, or a bad_args error naming ``key`` (element
    ``index`` of it, when given: a row of a list of rows)."""
    outer = [] if index is None else [index]
    label = key if index is None else f"{key}[{index}]"
    if not isinstance(value, list) or len(value) != n:
        raise bad_args(f"'{label}' must be a list of {n} numbers", key, **({"index": outer} if outer else {}),
                       expected_items=n)
    for i, v in enumerate(value):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise bad_args(f"'{label}' must hold finite numbers, got {v!r:.80}", key, index=[*outer, i])
    return [float(v) for v in value]


def choice(args: dict, key: str, allowed) -> str:
    """``args[key]`` if it is one of ``allowed`` (strings), else bad_args listing them."""
    value = args.get(key)
    if not isinstance(value, str) or value not in allowed:
        raise bad_args(f"'{key}' must be one of {', '.join(allowed)}, got {value!r:.80}", key, allowed=list(allowed))
    return value
