"""What the import contracts (pyproject.toml, run by ``lint-imports``) cannot see: an adapter that
reaches the simulation through the engine's attribute instead of an import."""

from __future__ import annotations

import ast
from pathlib import Path

import simd.adapters

ADAPTERS = Path(simd.adapters.__file__).parent


def test_adapters_use_the_engines_ports_never_its_simulation() -> None:
    reaches = []
    for path in sorted(ADAPTERS.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Attribute) and node.attr in ("sim", "navigator"):
                reaches.append(f"{path.relative_to(ADAPTERS)}:{node.lineno}: .{node.attr}")
    assert len(list(ADAPTERS.rglob("*.py"))) > 10  # the adapters were found
    assert reaches == [], "adapters use Engine.setup and the ports (simd/engine/ports.py):\n" + "\n".join(reaches)
