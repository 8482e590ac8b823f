"""KEY=VALUE options: the flag type and its reading, shared by `jaml.cli` and the figure
drivers' commands."""

from __future__ import annotations

import json
from typing import Annotated

import tyro

KeyValues = Annotated[tuple[str, ...], tyro.conf.UseAppendAction,
                      tyro.conf.arg(metavar="KEY=VALUE")]


def key_value(text: str) -> tuple[str, object]:
    """KEY=VALUE with VALUE read as JSON where it parses (numbers, true, lists), else a string."""
    if "=" not in text:
        raise ValueError(f"expected KEY=VALUE, got {text!r}")
    key, value = text.split("=", 1)
    try:
        return key, json.loads(value)
    except json.JSONDecodeError:
        return key, value


def key_values(items) -> dict[str, object]:
    """{KEY: VALUE} of KEY=VALUE texts; JSON lists become tuples (config ranges are tuples)."""
    pairs = (key_value(text) for text in items)
    return {k: tuple(v) if isinstance(v, list) else v for k, v in pairs}

