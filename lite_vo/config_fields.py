"""The :func:`param` field helper shared by every config section (no imports from the package)."""
from __future__ import annotations

from dataclasses import field
from typing import Any, Iterable


def param(default: Any, doc: str, lo: float | None = None, hi: float | None = None,
          choices: Iterable[Any] | None = None):
    """A config field with a doc line and a valid range ``[lo, hi]`` or a set of choices."""
    return field(default=default, metadata={
        "doc": doc, "lo": lo, "hi": hi, "choices": tuple(choices) if choices is not None else None})
