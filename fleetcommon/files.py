"""Errors and YAML helpers shared by the strict file loaders (worlds, fleets).

Both loaders decode untrusted text that a person typed; both report where (the file, and a
msgspec location or a line and column) and why, the same way.
"""

from __future__ import annotations

import difflib
import os
import re
from dataclasses import dataclass
from pathlib import Path

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


#: msgspec's validation messages end in `` - at `$.path` ``.
AT_LOCATION = re.compile(r"^(?P<reason>.*) - at `(?P<location>\$[^`]*)`$", re.DOTALL)


def split_location(message: str) -> tuple[str, str | None]:
    """(reason, ``$.location``) of a msgspec validation message; the location may be absent."""
    match = AT_LOCATION.match(message)
    return (match["reason"], match["location"]) if match else (message, None)


@dataclass(frozen=True)
class ShippedFiles:
    """YAML files shipped in a package folder and found by bare name, or any file by path.

    A bare name has no path separator and none of ``path_suffixes``; anything else is a path,
    so a local file never shadows a shipped one by accident.
    """

    kind: str  # "world", "fleet": used in messages
    directory: Path
    error: type[FileFormatError]
    #: the endings that make a name without a separator a path (a world may also be a ``.map``)
    path_suffixes: tuple[str, ...] = (".yaml", ".yml")

    def names(self) -> list[str]:
        return sorted(p.stem for p in self.directory.glob("*.yaml"))

    def read(self, name_or_path: str | os.PathLike[str]) -> tuple[bytes, str]:
        """The file's bytes and the source to name in messages; raises ``self.error``."""
        path, source = self._resolve(name_or_path)
        try:
            return path.read_bytes(), source
        except FileNotFoundError:
            raise self.error(source, "file not found" + self._shipped_hint(path)) from None
        except IsADirectoryError:
            raise self.error(source, f"is a directory, not a {self.kind} file") from None
        except OSError as exc:
            raise self.error(source, f"cannot read file: {exc.strerror or exc}") from None

    def _resolve(self, name_or_path: str | os.PathLike[str]) -> tuple[Path, str]:
        if not (isinstance(name_or_path, str) and _is_bare_name(name_or_path, self.path_suffixes)):
            return Path(name_or_path), os.fspath(name_or_path)
        available = self.names()
        if name_or_path not in available:
            close = difflib.get_close_matches(name_or_path, available, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else "."
            listing = ", ".join(available) or "(none)"
            raise self.error(
                name_or_path,
                f"unknown {self.kind}{hint} Available {self.kind}s: {listing}. "
                f"A file path must contain '/' or end in {_either(self.path_suffixes)}",
            )
        path = self.directory / f"{name_or_path}.yaml"
        return path, str(path)

    def _shipped_hint(self, path: Path) -> str:
        if path.suffix in (".yaml", ".yml") and path.stem in self.names():
            return f" (for the shipped {self.kind}, pass the bare name {path.stem!r})"
        return ""


def _either(words: tuple[str, ...]) -> str:
    return " or ".join(words) if len(words) < 3 else f"{', '.join(words[:-1])} or {words[-1]}"


def _is_bare_name(text: str, path_suffixes: tuple[str, ...]) -> bool:
    separators = {"/", os.sep} | ({os.altsep} if os.altsep else set())
    return not any(s in text for s in separators) and not text.endswith(path_suffixes)
