"""One error policy for every console script: a user's mistake is one line, exit status 2.

:func:`console_main` wraps a script's ``main(argv)``. Errors that come from the user's
arguments, files or file system (``ValueError``, ``TypeError``, ``OSError``, ``EOFError``
and their subclasses, e.g. ``FileNotFoundError``, ``json.JSONDecodeError``) are printed as
``<prog>: error: <message>`` on one line to stderr and the script returns 2. ``--debug``
anywhere on the command line (removed before the script parses it) lets them propagate with
their traceback. ``raise SystemExit("message")`` is printed the same way and becomes
``SystemExit(2)``, as argparse's errors. ``KeyboardInterrupt`` prints one line and returns
130. Other exceptions are bugs and keep their traceback.
"""

from __future__ import annotations

import argparse
import functools
import sys
from collections.abc import Callable, Sequence
from typing import Any

__all__ = ["DEBUG_FLAG", "USER_ERRORS", "console_main", "number_arg", "one_line"]

DEBUG_FLAG = "--debug"  # command-line flag that shows the traceback of a user error
# exception types that report a problem with the user's input, not a bug
USER_ERRORS: tuple[type[BaseException], ...] = (ValueError, TypeError, OSError, EOFError)
_MAX_MESSAGE = 500  # characters of a one-line message kept (longer ones are cut)

MainFunction = Callable[[Sequence[str] | None], int | None]


def one_line(err: BaseException) -> str:
    """``err`` as one line: its message with newlines folded, its type when it has none."""
    text = " ".join(str(err).split())
    if isinstance(err, OSError) and err.filename is not None and str(err.filename) not in text:
        text = f"{text}: {err.filename}"
    if not text:
        text = type(err).__name__
    if len(text) > _MAX_MESSAGE:
        text = text[: _MAX_MESSAGE - 3] + "..."
    return text


def console_main(prog: str) -> Callable[[MainFunction], Callable[..., int]]:
    """Decorator for the ``main(argv)`` of console script ``prog`` (see the module docstring).

    The wrapped function takes ``argv`` (default ``sys.argv[1:]``) and returns the exit
    status: what ``main`` returned (None counts as 0), 2 on a user error, 130 on Ctrl-C
    (``SystemExit`` with a message becomes ``SystemExit(2)``).
    """

    def decorate(main: MainFunction) -> Callable[..., int]:
        @functools.wraps(main)
        def wrapped(argv: Sequence[str] | None = None) -> int:
            args = list(sys.argv[1:] if argv is None else argv)
            debug = DEBUG_FLAG in args
            args = [a for a in args if a != DEBUG_FLAG]
            try:
                status = main(args)
            except USER_ERRORS as err:
                if debug:
                    raise
                print(
                    f"{prog}: error: {one_line(err)} (run with {DEBUG_FLAG} for the traceback)",
                    file=sys.stderr,
                )
                return 2
            except SystemExit as stop:  # raise SystemExit("message"): a user error as well
                if debug or stop.code is None or isinstance(stop.code, int):
                    raise
                print(f"{prog}: error: {' '.join(str(stop.code).split())}", file=sys.stderr)
                raise SystemExit(2) from None  # as argparse's parser.error
            except KeyboardInterrupt:
                if debug:
                    raise
                print(f"{prog}: interrupted", file=sys.stderr)
                return 130
            return 0 if status is None else int(status)

        return wrapped

    return decorate


def number_arg(
    lo: float | None = None,
    hi: float | None = None,
    *,
    integer: bool = False,
    lo_open: bool = False,
    hi_open: bool = False,
) -> Callable[[str], Any]:
    """An argparse ``type`` for a number flag: finite, within ``[lo, hi]`` (bounds excluded
    with ``lo_open`` / ``hi_open``), an integer with ``integer`` (``1e3`` reads as 1000);
    argparse prints ``argument --flag: value must be ... got ...`` and exits 2
    (:func:`mcpilco.envs.numbers.check_number`)."""
    from mcpilco.envs.numbers import check_number

    def parse(text: str) -> Any:
        try:
            value: Any = int(text) if integer else float(text)
        except ValueError:
            try:
                value = float(text)
            except ValueError:
                value = text
        try:
            return check_number(
                value, "value", lo=lo, hi=hi, integer=integer, lo_open=lo_open, hi_open=hi_open
            )
        except ValueError as err:
            raise argparse.ArgumentTypeError(str(err)) from None

    parse.__name__ = "integer" if integer else "number"  # argparse names the type with it
    return parse
