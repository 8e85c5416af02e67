"""What the options and arguments of ``grasp_envs`` accept, and errors that name the argument and its value.

Each task's options are one frozen dataclass (``Reacher2DOptions``, ..., ``Grasper3DOptions``; the scripted starts'
are ``ScriptedStartOptions``): a field per option, with its type, its default and its ``Rule`` (``option(default,
rule)``), every field checked when the dataclass is made, rules that tie options together checked in its
``__post_init__``. Other arguments (those of the batched engine) are checked against a table of rules
(``check_arguments``). A bad option raises ``ArgumentError("<name> must be <requirement>, got <value>")``, a bad argument
``ArgumentError("<owner>: `<name>` must be ...")`` (a ``ValueError``), and a keyword that is no option ``TypeError``
naming it. Booleans are ``bool`` only; integers are ``int`` (or numpy
integers), never ``bool`` or ``float``; numbers are finite ``int`` or ``float`` (or numpy numbers), never ``bool``.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Collection, Iterable, Mapping
from dataclasses import dataclass, field, fields
from typing import Any, NamedTuple, TypeVar

import numpy as np

OptionsT = TypeVar("OptionsT", bound="Options")


class Rule(NamedTuple):
    """What one option or argument accepts, and that requirement in words (as the error message states it)."""

    accepts: Callable[[Any], bool]
    requirement: str


def is_int(value: Any) -> bool:
    return isinstance(value, int | np.integer) and not isinstance(value, bool)


def is_number(value: Any) -> bool:
    """A finite real number: ``int`` or ``float`` or a numpy one, never ``bool``."""
    if not isinstance(value, int | float | np.integer | np.floating) or isinstance(value, bool):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:  # an int beyond float's range
        return False


def is_keywords(value: Any) -> bool:
    """A dict that can be passed as ``**value``: its keys are ``str``."""
    return isinstance(value, dict) and all(isinstance(key, str) for key in value)


def is_names(value: Any) -> bool:
    """A list or tuple of ``str`` (one ``str`` is a sequence of characters, not of names)."""
    return isinstance(value, list | tuple) and all(isinstance(item, str) for item in value)


def amount(*, positive: bool = False, optional: bool = False) -> Rule:
    """A number > 0 (``positive``) or >= 0; or None, where ``optional``."""

    def accepts(value: Any) -> bool:
        if optional and value is None:
            return True
        return is_number(value) and (value > 0 or (value == 0 and not positive))

    return Rule(accepts, f"a {'positive' if positive else 'non-negative'} number" + (" or None" if optional else ""))


def integer(minimum: int, *, optional: bool = False) -> Rule:
    """An integer >= ``minimum``; or None, where ``optional``."""
    return Rule(
        lambda value: (optional and value is None) or (is_int(value) and value >= minimum),
        ("None or " if optional else "") + f"an integer >= {minimum}",
    )


def flag(*, optional: bool = False) -> Rule:
    """A bool; or None, where ``optional``."""
    if optional:
        return Rule(lambda value: value is None or isinstance(value, bool), "a bool or None")
    return Rule(lambda value: isinstance(value, bool), "a bool (True or False)")


def choice(choices: Iterable[Any]) -> Rule:
    """One of ``choices`` (``str``, and ``None`` where it is one of them)."""
    options = list(choices)
    return Rule(
        lambda value: any(value is item or (isinstance(value, str) and value == item) for item in options),
        f"one of {options}",
    )


def path(*, optional: bool = False) -> Rule:
    """A file path (``str`` or ``os.PathLike``); or None, where ``optional``."""
    return Rule(
        lambda value: (optional and value is None) or isinstance(value, str | os.PathLike),
        "a path (str)" + (" or None" if optional else ""),
    )


class ArgumentError(ValueError):
    """An argument, or a combination of arguments, that cannot work; the message names each as the caller wrote it."""


def got(value: Any, *, with_type: bool = False) -> str:
    """``"got <value>"`` (``"got <type> <value>"`` ``with_type``) for an error message; a number that arrives as a
    ``str`` (from YAML: a recipe, ``--set``) says why, since YAML 1.1 reads ``6e-4`` as a string."""
    text = f"got {type(value).__name__} {value!r}" if with_type else f"got {value!r}"
    if isinstance(value, str):
        try:
            float(value)
        except ValueError:
            return text
        return f"{text} (a number as a str; YAML 1.1 reads 6e-4 as one: write !!float {value} in YAML)"
    return text


def check(name: str, value: Any, rule: Rule) -> None:
    """Raise :class:`ArgumentError` ``"<name> must be <requirement>, got <value>"`` unless ``rule`` accepts ``value``
    (an option of a task's options dataclass)."""
    if not rule.accepts(value):
        raise ArgumentError(f"{name} must be {rule.requirement}, {got(value)}")


def check_arguments(owner: str, rules: Mapping[str, Rule], arguments: Mapping[str, Any]) -> None:
    """Raise :class:`ArgumentError` naming the first of ``arguments`` that breaks its rule:
    ``"<owner>: `<name>` must be <requirement>, got <value>"``. The one argument check of ``grasp_envs`` and
    ``sb3_trpo_plus``."""
    for name, value in arguments.items():
        rule = rules[name]
        if not rule.accepts(value):
            raise ArgumentError(f"{owner}: `{name}` must be {rule.requirement}, {got(value)}")


def option(default: Any, rule: Rule) -> Any:
    """A field of an options dataclass: its default and the rule its value is checked by."""
    return field(default=default, metadata={"rule": rule})


@dataclass(frozen=True)
class Options:
    """Base of the options dataclasses (each ``@dataclass(frozen=True)``, every field made by ``option``).

    Making one checks every field by its rule, in the fields' order; a subclass that ties options together checks
    that in its own ``__post_init__`` after calling this one. An unknown keyword raises ``TypeError`` (the dataclass's
    own, or ``from_keywords``' naming the owner).
    """

    def __post_init__(self) -> None:
        for spec in fields(self):
            check(spec.name, getattr(self, spec.name), spec.metadata["rule"])

    @classmethod
    def names(cls) -> tuple[str, ...]:
        """The options' names, in their order."""
        return tuple(spec.name for spec in fields(cls))

    @classmethod
    def defaults(cls) -> dict[str, Any]:
        """Every option's default."""
        return {spec.name: spec.default for spec in fields(cls)}

    @classmethod
    def from_keywords(
        cls: type[OptionsT], keywords: Mapping[str, Any], owner: str, others: Collection[str] = ()
    ) -> tuple[OptionsT, dict[str, Any]]:
        """The options given in ``keywords`` (the others at their defaults), and the keywords named in ``others``
        (those the owner takes besides its options); ``TypeError`` naming any other keyword."""
        names = cls.names()
        unknown = sorted(set(keywords) - {*names, *others})
        if unknown:
            raise TypeError(f"{owner} has no option {', '.join(map(repr, unknown))}")
        options = cls(**{name: value for name, value in keywords.items() if name in names})
        return options, {name: value for name, value in keywords.items() if name not in names}

    def keywords(self) -> dict[str, Any]:
        """Every option and its value, as keyword arguments."""
        return {name: getattr(self, name) for name in self.names()}
