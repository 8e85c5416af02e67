"""What user-facing arguments accept, and errors that name the argument and its value.

Each constructor keeps a table ``{argument: Rule}`` and checks its arguments with :func:`check_arguments` before it
builds anything. Booleans are ``bool`` only; integers are ``int`` (or numpy integers), never ``bool`` or ``float``;
numbers are finite ``int`` or ``float`` (or numpy numbers), never ``bool`` or ``str``; sequences of names are lists
or tuples of ``str``, never one ``str``; ``None`` only where the argument's default is ``None``. A bad argument, or a
combination of arguments that cannot work, raises :class:`ArgumentError`; a command line's parser
(:class:`CommandLineParser`) says what is wrong with it in one line.
"""

from __future__ import annotations

import argparse
import types
from collections.abc import Callable, Sequence
from typing import Any, NoReturn

# the primitives and the check are grasp_envs' (the options of its tasks follow the same rules)
from grasp_envs.options import ArgumentError, Rule, check_arguments, got, integer, is_int, is_keywords, is_names
from grasp_envs.options import is_number as is_finite_number

__all__ = [
    "ArgumentError",
    "CommandLineParser",
    "Rule",
    "boolean",
    "check_arguments",
    "choice",
    "got",
    "integer",
    "is_bool",
    "is_finite_number",
    "is_int",
    "is_keywords",
    "is_names",
    "is_schedule",
    "keywords",
    "names",
    "number",
    "optional",
]


class CommandLineParser(argparse.ArgumentParser):
    """argparse's parser whose errors are one line, ``<prog>: error: <message> (<prog> --help)``, exit status 2 (argparse
    prints its usage block first)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} ({self.prog} --help)\n")


def is_bool(value: Any) -> bool:
    return isinstance(value, bool)


def is_schedule(value: Any) -> bool:
    """A function of the remaining progress (a class is callable too, but is no schedule)."""
    return callable(value) and not isinstance(value, type)


def boolean() -> Rule:
    return Rule(is_bool, "a bool (True or False)")


def number(condition: Callable[[float], bool], text: str, *, schedule: bool = False, optional: bool = False) -> Rule:
    """A finite int or float satisfying ``condition`` (``text`` in words); or a schedule, or None, where allowed."""

    def accepts(value: Any) -> bool:
        if (optional and value is None) or (schedule and is_schedule(value)):
            return True
        return is_finite_number(value) and condition(float(value))

    return Rule(accepts, ("None or " if optional else "") + f"a finite number {text}" + (" or a schedule" if schedule else ""))


def optional(kind: type | types.UnionType, text: str) -> Rule:
    """None or an instance of ``kind`` (``text`` in words)."""
    return Rule(lambda value: value is None or isinstance(value, kind), f"None or {text}")


def names(*, optional: bool = False) -> Rule:
    """A list or tuple of ``str`` (:func:`is_names`); or None, where ``optional``."""
    return Rule(
        lambda value: (optional and value is None) or is_names(value),
        ("None or " if optional else "") + "a list or tuple of str (not one str)",
    )


def keywords(text: str, *, optional: bool = True) -> Rule:
    """A dict with ``str`` keys (keyword arguments; ``text`` says whose); or None, where ``optional``."""
    return Rule(
        lambda value: (optional and value is None) or is_keywords(value),
        ("None or " if optional else "") + f"a dict of {text} (str keys)",
    )


def choice(options: Sequence[str], *, optional: bool = False) -> Rule:
    """One of the ``str`` ``options``; or None, where ``optional``."""
    return Rule(
        lambda value: (optional and value is None) or (isinstance(value, str) and value in options),
        ("None or " if optional else "") + f"one of {list(options)}",
    )
