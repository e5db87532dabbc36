"""Errors and YAML helpers shared by the strict file loaders (worlds, fleets).

Both loaders decode untrusted text that a person typed; both report where (the file, and a
msgspec location or a line and column) and why, the same way.
"""

from __future__ import annotations

import msgspec
import yaml


class FileFormatError(Exception):
    """A file that cannot be used. ``source``, ``location`` and ``reason`` stay available so
    callers can map the error without parsing its message."""

    def __init__(self, source: str, reason: str, location: str | None = None) -> None:
        self.source = source
        self.location = location
        self.reason = reason
        where = f"{source}: {location}" if location else source
        super().__init__(f"{where}: {reason}")


def yaml_syntax_problem(exc: msgspec.DecodeError) -> tuple[str, str | None]:
    """(reason, "line L, column C") of a YAML syntax error raised through msgspec.yaml.

    msgspec re-raises PyYAML's error as plain text; the original, with its mark, is still
    reachable as the suppressed context.
    """
    original = exc.__context__
    if isinstance(original, yaml.MarkedYAMLError) and original.problem_mark is not None:
        mark = original.problem_mark
        problem = original.problem or "malformed YAML"
        if original.context:
            problem = f"{problem} ({original.context})"
        return f"YAML syntax error: {problem}", f"line {mark.line + 1}, column {mark.column + 1}"
    return "YAML syntax error: " + " ".join(str(exc).split()), None
