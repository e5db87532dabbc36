"""How robots are ordered for people: by name, with numbers compared as numbers."""

from __future__ import annotations

import re


def natural_key(name: str) -> tuple[str | int, ...]:
    """Sort key that puts ``burger_2`` before ``burger_10`` (and ``r2`` before ``r10``).

    Digit runs compare as numbers, the rest as text; a tuple of alternating text and numbers,
    so that two keys always compare (they start with text, even if empty)."""
    return tuple(int(p) if p.isdigit() else p for p in re.split(r"(\d+)", name))
