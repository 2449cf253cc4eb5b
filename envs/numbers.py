"""Numbers from a user, checked where they are parsed: type, finiteness and range.

A number from a task file, a config file, ``--set`` or a command-line flag is checked by
:func:`check_number` before it is used: a boolean or a string is not a number, NaN and
infinities are refused where a finite value is needed, and the value must lie in the field's
range. The error is one line that names the field and the allowed range, e.g.
``task.dt must be a finite number in (0, 3600], got 1e+308``.
"""

from __future__ import annotations

import math
import numbers
import reprlib
from typing import Any

__all__ = ["check_number", "shown"]

_SHOW = reprlib.Repr()  # short reprs of user values in messages
_SHOW.maxstring = 60
_SHOW.maxother = 60
_SHOW.maxlist = _SHOW.maxdict = _SHOW.maxtuple = 6
_SHOW.maxlevel = 2


def shown(value: Any) -> str:
    """A short ``repr`` of a user value for an error message (long or nested values cut)."""
    return _SHOW.repr(value)


def _text(v: float) -> str:
    return str(v) if isinstance(v, int) else f"{v:g}"


def _range_text(lo: float | None, hi: float | None, lo_open: bool, hi_open: bool) -> str:
    if lo is None and hi is None:
        return ""
    if hi is None:
        return f" {'>' if lo_open else '>='} {_text(lo)}"
    if lo is None:
        return f" {'<' if hi_open else '<='} {_text(hi)}"
    return f" in {'(' if lo_open else '['}{_text(lo)}, {_text(hi)}{')' if hi_open else ']'}"


def check_number(
    value: Any,
    name: str,
    *,
    lo: float | None = None,
    hi: float | None = None,
    lo_open: bool = False,
    hi_open: bool = False,
    integer: bool = False,
) -> Any:
    """``value`` as a finite ``float`` (``int`` with ``integer``) within the range.

    Args:
        value: what the user gave (an ``int`` or ``float``; ``bool`` and ``str`` are refused;
            a float with an integral value is accepted where an integer is needed).
        name: the field or argument, for the message (``"task.dt"``, ``"--particles"``).
        lo, hi: the bounds (None: unbounded on that side).
        lo_open, hi_open: the bound itself is excluded.
        integer: the value must be an integer.

    Raises:
        ValueError: one line naming ``name``, the allowed range and the value.
    """
    kind = "an integer" if integer else "a finite number"
    expected = kind + _range_text(lo, hi, lo_open, hi_open)
    # numbers.Real: Python and numpy ints and floats; booleans (numpy's too) are not numbers
    number = isinstance(value, numbers.Real) and type(value).__name__ not in ("bool", "bool_")
    if not number or not math.isfinite(float(value)):
        raise ValueError(f"{name} must be {expected}, got {shown(value)}")
    if integer:
        if float(value) != int(value):
            raise ValueError(f"{name} must be {expected}, got {shown(value)}")
        value = int(value)
    else:
        value = float(value)
    if (lo is not None and (value <= lo if lo_open else value < lo)) or (
        hi is not None and (value >= hi if hi_open else value > hi)
    ):
        raise ValueError(f"{name} must be {expected}, got {shown(value)}")
    return value
