"""Argument types shared by the subcommands (``argparse`` ``type=`` callables).

One home for the parsing every command needs the same way, so that a malformed value is the same
one-line usage error (exit 2) whichever command it is given to.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from typing import Any


def json_object(name: str) -> Callable[[str], dict[str, Any]]:
    """A ``type=`` that parses a JSON object (``--turbine '{"preset": "nrel-5mw"}'``); anything else
    (invalid JSON, a list, a number) is an ``ArgumentTypeError`` naming the option."""
    def parse(text: str) -> dict[str, Any]:
        try:
            value = json.loads(text)
        except json.JSONDecodeError as exc:
            raise argparse.ArgumentTypeError(f"{name} must be JSON, e.g. '{{\"key\": 1}}': {exc}") from None
        if not isinstance(value, dict):
            raise argparse.ArgumentTypeError(f"{name} must be a JSON object, got {text!r}")
        return value
    return parse


def float_or_auto(name: str) -> Callable[[str], float | None]:
    """A ``type=`` for a number or ``auto`` (returned as ``None``: let the program choose)."""
    def parse(text: str) -> float | None:
        if text.strip().lower() == "auto":
            return None
        try:
            return float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be a number or 'auto', got {text!r}") from None
    return parse
