"""World files shipped with fleetsim.

A package rather than a data folder so that the YAML files travel as package data with an
installed wheel and can be found without knowing where the checkout lives.
"""

from __future__ import annotations

from pathlib import Path

WORLDS_DIR = Path(__file__).parent


def world_path(name: str) -> Path:
    """Where the shipped world ``name`` would live; existence is the loader's concern."""
    return WORLDS_DIR / f"{name}.yaml"


def list_worlds() -> list[str]:
    return sorted(p.stem for p in WORLDS_DIR.glob("*.yaml"))
