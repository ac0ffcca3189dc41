"""Shared by every command: the one-line user error, option parsing helpers."""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import sys

from benchmark.common.settings import SettingError, choices_of, hints, kind_of
from benchmark.trial.cell import CELL_FIELDS, CellSpec
from benchmark.trial.registry import POLICIES
from sims import ENGINES, load_entry_point


class CliError(SettingError):
    """A user mistake: reported as one line, exit code 2."""


def key_values(items: list[str], option: str, form: str) -> dict[str, str]:
    """`KEY=VALUE` words of an option as a dict; anything else is a one-line error."""
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise CliError(f"{option} expects {form}, got '{item}'")
        out[key] = value
    return out


def _as_typed(name: str) -> str:
    """The command line that ran `bench NAME`, to print in the report it writes."""
    return " ".join([f"bench {name}", *sys.argv[2:]]) if sys.argv[1:2] == [name] else f"bench {name}"


GIVEN = argparse.SUPPRESS  # settings appear in the namespace only when given: defaults live in the dataclasses


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, not a usage dump
        raise CliError(f"{message} (see '{self.prog} --help')")


def _doc(module: str) -> str:
    """A command's long help: the docstring of the module that implements it."""
    return importlib.import_module(module).__doc__ or ""


def _number(kind: type, positive: bool = False):
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a {kind.__name__}, got '{text}'") from None
        if positive and not value > 0:
            raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
        return value

    parse.__name__ = f"{'positive ' if positive else ''}{kind.__name__}"
    return parse


def add_fields(parser, cls: type, names: list[str] | None = None, dests: dict | None = None) -> None:
    """One option per field of the settings dataclass `cls` that has help: its default, help and
    choices come from the field; the value is typed and checked later, with the field's own rules."""
    for f in dataclasses.fields(cls):
        if "help" not in f.metadata or (names is not None and f.name not in names) or f.name in (dests or {}):
            continue
        flag = f.metadata.get("flag") or "--" + f.name.replace("_", "-")
        valid = choices_of(f)
        default = "+".join(f.default) if isinstance(f.default, tuple) else f.default
        text = f.metadata["help"] + (f"; one of: {', '.join(valid)}" if valid and "one of" not in f.metadata["help"]
                                     else "") + (f" (default {default})" if default is not None else "")
        kind, options = kind_of(hints(cls)[f.name]), {}
        if kind == "boolean":
            options["action"] = argparse.BooleanOptionalAction
        elif kind == "list of names":
            options["nargs"] = "+"
        elif kind in ("integer", "number"):
            options["type"] = _number(int if kind == "integer" else float, f.metadata.get("positive", False))
        parser.add_argument(flag, dest=f.name, default=GIVEN, help=text.replace("%", "%%"), **options)
        if dests is not None:
            dests[f.name] = flag


def _cell_options(parser, policies: bool = True) -> None:
    add_fields(parser, CellSpec, [n for n in CELL_FIELDS if policies or n != "policy"])
    seen: dict = {}
    for record in ENGINES.values():
        if record.options:
            add_fields(parser.add_argument_group(f"{record.title} options"), load_entry_point(record.options),
                       dests=seen)
    if policies:  # a setting two policies share (the protocol's timing) is one option, listed with the first
        shared: dict = {}
        for entry in POLICIES.values():
            if entry.settings:
                add_fields(parser.add_argument_group(f"--policy {entry.name}: {entry.help}"), entry.settings_class(),
                           dests=shared)
