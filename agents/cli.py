"""What the command lines of :mod:`agents` share: argument types.

>>> import argparse
>>> parser = argparse.ArgumentParser()
>>> _ = parser.add_argument("--env-kwargs", type=json_object, default="{}")
>>> parser.parse_args(["--env-kwargs", '{"layout": "loop"}']).env_kwargs
{'layout': 'loop'}
>>> parser.parse_args([]).env_kwargs
{}
"""

from __future__ import annotations

import argparse
import json
from typing import Any

__all__ = ["json_object"]


def json_object(text: str) -> dict[str, Any]:
    """An ``argparse`` type: ``text`` read as a JSON object (a usage error naming the option otherwise)."""
    try:
        value = json.loads(text)
    except json.JSONDecodeError as error:
        raise argparse.ArgumentTypeError(f"not valid JSON: {error}") from None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError(f"expected a JSON object, got {text!r}")
    return value
