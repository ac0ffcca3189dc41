"""Settings as data: dataclass fields carry their default, help text and valid choices once, and
every value from the command line, an experiment file or `--set` is typed and checked here.

    @dataclass(frozen=True)
    class MySettings:
        history: int = setting(50, "observation/action pairs in the prompt", minimum=0)
"""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Callable, Sequence
from functools import cache


class SettingError(ValueError):
    """A setting with a wrong name, type or value: one line for the user."""


def setting(default, help: str, choices: Sequence[str] | Callable[[], Sequence[str]] | None = None,
            minimum: float | None = None, positive: bool = False, flag: str | None = None, noun: str | None = None,
            added_later: bool = False):
    """A dataclass field whose metadata the CLI and validation read (help, choices, range, and the
    command-line flag when it is not `--field-name`). `added_later`: a setting that came after results were
    stored; at its default it is left out of trial ids, so the stores made before it stay valid."""
    meta = {"help": help, "choices": choices, "minimum": minimum, "positive": positive, "flag": flag, "noun": noun,
            "added_later": added_later}
    if isinstance(default, (list, dict)):
        raise TypeError("use a tuple for a sequence default")
    return dataclasses.field(default=default, metadata=meta)


def choices_of(f: dataclasses.Field) -> list[str] | None:
    found = f.metadata.get("choices")
    return list(found() if callable(found) else found) if found is not None else None


@cache
def hints(cls: type) -> dict[str, typing.Any]:
    return typing.get_type_hints(cls)


def _base(hint) -> tuple[typing.Any, bool]:
    """(the type without Optional, whether None is allowed)."""
    args = typing.get_args(hint)
    if type(None) in args:
        rest = [a for a in args if a is not type(None)]
        return rest[0], True
    return hint, False


def kind_of(hint) -> str:
    base, _ = _base(hint)
    if typing.get_origin(base) is tuple:
        return "list of names"
    return {int: "integer", float: "number", bool: "boolean", str: "text"}.get(base, str(base))


def coerce(value, hint, key: str):
    """`value` (from TOML, JSON or the command line) as the field type `hint`, or a SettingError."""
    base, optional = _base(hint)
    if hasattr(value, "item") and not isinstance(value, (str, list, tuple)):  # a numpy scalar from a store
        value = value.item()
    if isinstance(value, float) and value != value:  # NaN: a column this cell does not use
        value = None
    if value is None or (optional and isinstance(value, str) and value.lower() in ("none", "null")):
        if optional:
            return None
        raise SettingError(f"setting '{key}' needs a {kind_of(hint)}, got nothing")
    kind = kind_of(hint)
    wrong = SettingError(f"setting '{key}' expects {'an' if kind[0] in 'aeiou' else 'a'} {kind}, got {value!r}")
    if typing.get_origin(base) is tuple:
        items = value.replace(",", " ").split() if isinstance(value, str) else value
        if not isinstance(items, (list, tuple)) or not all(isinstance(i, str) for i in items):
            raise wrong
        return tuple(items)
    if base is bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, str) and value.lower() in ("true", "false", "yes", "no", "1", "0"):
            return value.lower() in ("true", "yes", "1")
        raise wrong
    if base in (int, float):
        if isinstance(value, bool):
            raise wrong
        if isinstance(value, str):
            try:
                value = base(value)
            except ValueError:
                raise wrong from None
        if base is int and isinstance(value, float):
            if not value.is_integer():
                raise wrong
            value = int(value)
        if not isinstance(value, (int, float)):
            raise wrong
        return base(value)
    if base is str:
        if not isinstance(value, str):
            raise wrong
        return value
    return value


def check(f: dataclasses.Field, value, key: str | None = None) -> None:
    """Range and choice checks from a field's metadata."""
    key = key or f.name
    if value is None:
        return
    valid = choices_of(f)
    if valid is not None:
        for item in value if isinstance(value, tuple) else (value,):
            if item not in valid:
                noun = f.metadata.get("noun") or key.replace("_", " ")
                raise SettingError(f"unknown {noun} '{item}'; valid: {', '.join(valid)}")
    if f.metadata.get("positive") and not value > 0:
        raise SettingError(f"{key} must be > 0, got {value}")
    low = f.metadata.get("minimum")
    if low is not None and value < low:
        raise SettingError(f"{key} must be >= {low:g}, got {value}")


def build(cls: type, values: dict, where: str = "settings"):
    """An instance of the settings dataclass `cls` from loosely typed `values`, every field checked."""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = [k for k in values if k not in fields]
    if unknown:
        raise SettingError(f"{where}: unknown setting '{unknown[0]}'; valid: {', '.join(fields)}")
    typed = {}
    for key, value in values.items():
        typed[key] = coerce(value, hints(cls)[key], key)
        check(fields[key], typed[key])
    try:
        return cls(**typed)
    except TypeError as err:
        raise SettingError(f"{where}: {err}") from None
