"""Config errors of this package's policies, and how ``lerobot-train`` gets to show them.

Both policy configs validate themselves in ``__post_init__`` (LeRobot's convention) and raise
:class:`PolicyConfigError`, a ``ValueError``. Built from Python, that error is what the caller
sees. Built by LeRobot's CLI, the config is instantiated by draccus, whose
``decoding.decode_dataclass`` turns every ``TypeError`` / ``ValueError`` of a constructor into a
``ParsingError("Couldn't instantiate class ... using the given arguments.")`` chained to the
original (``__cause__``); LeRobot's ``parser.wrap`` then prints only ``str()`` of the outer
``DecodingError`` and exits, so the config's own message was lost.

:func:`surface_config_errors_in_draccus` fixes that for this package's configs only: it wraps
``draccus.parsers.decoding.decode_dataclass`` (the function ``decode_choice_class`` looks up by
name for every ``--policy.type=...`` and ``--policy.path`` decoding) so that a ``ParsingError``
whose cause is a :class:`PolicyConfigError` is re-raised as a ``DecodingError`` carrying that
message. Every other exception, and every other class's decoding, passes through the original
function unchanged, so LeRobot's behaviour for other policies does not change. The wrapper is
installed when this module is imported, which the policy configuration modules do, and LeRobot's
plugin scan imports those before it parses the command line. A test checks that
``lerobot-train`` prints the message, so a draccus release that renames the function shows up.
"""

from __future__ import annotations

import functools
from collections.abc import Iterable
from typing import Any


class PolicyConfigError(ValueError):
    """A policy config value that cannot work; the message names the field and the rule."""


# -- checks used by the configs' __post_init__ ------------------------------------------------------
def require(condition: bool, message: str) -> None:
    """Raise :class:`PolicyConfigError` with ``message`` unless ``condition`` holds."""
    if not condition:
        raise PolicyConfigError(message)


def require_ints(config: Any, names: Iterable[str], minimum: int = 1, why: str = "") -> None:
    """Each named field is an ``int`` (not a bool) ``>= minimum``."""
    for name in names:
        value = getattr(config, name)
        ok = isinstance(value, int) and not isinstance(value, bool) and value >= minimum
        require(ok, f"`{name}` must be an integer >= {minimum}, got {value!r}{why}")


def require_positive(config: Any, names: Iterable[str]) -> None:
    """Each named field is a real number ``> 0``."""
    for name in names:
        value = getattr(config, name)
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and value > 0
        require(ok, f"`{name}` must be > 0, got {value!r}")


def require_non_negative(config: Any, names: Iterable[str]) -> None:
    """Each named field is a real number ``>= 0``."""
    for name in names:
        value = getattr(config, name)
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and value >= 0
        require(ok, f"`{name}` must be >= 0, got {value!r}")


def require_probability(config: Any, names: Iterable[str]) -> None:
    """Each named field (a dropout rate) is in ``[0, 1)``."""
    for name in names:
        value = getattr(config, name)
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and 0 <= value < 1
        require(ok, f"`{name}` must be in [0, 1), got {value!r}")


def require_choice(config: Any, name: str, choices: Iterable[str]) -> None:
    """The named field is one of ``choices``."""
    choices = tuple(choices)
    value = getattr(config, name)
    require(value in choices, f"`{name}` must be one of {choices}, got {value!r}")


# -- the draccus hook -----------------------------------------------------------------------------
def surface_config_errors_in_draccus() -> bool:
    """Install the wrapper described in the module docstring (idempotent); returns whether it is
    installed (False only if this draccus has no ``decode_dataclass`` to wrap)."""
    from draccus.parsers import decoding
    from draccus.utils import DecodingError, ParsingError

    original = getattr(decoding, "decode_dataclass", None)
    if original is None:
        return False
    if getattr(original, "_surfaces_policy_config_errors", False):
        return True

    @functools.wraps(original)
    def decode_dataclass(cls, d, path=()):
        try:
            return original(cls, d, path)
        except ParsingError as e:
            cause = e.__cause__
            if isinstance(cause, PolicyConfigError) and not isinstance(e, DecodingError):
                raise DecodingError(tuple(path), str(cause)) from cause
            raise

    decode_dataclass._surfaces_policy_config_errors = True
    decoding.decode_dataclass = decode_dataclass
    return True


surface_config_errors_in_draccus()
