"""Which robots a ``P/robots`` request asks for: all of them, the ones it names, or a page.

The whole list of 20 000 robots is 16 MB of MessagePack: answering it takes a daemon tens of
milliseconds and the network as long again, and a tool that wants one robot's record, or shows
a screenful, pays all of it. So a list request may name robots (``names``: their records only,
in spawn order) or ask for a page (``limit`` records in name order, the first ones whose name
sorts after ``after``), as paged listings do elsewhere (``kubectl get --limit --continue``).
A page is found by name, not by position, so the next page is right even when robots came
and went in between, and several daemons' pages merge into one (each daemon gives its own
first ``limit`` after the same name; the client keeps the first ``limit`` of them all by name,
:func:`select`).

Pure, so that the daemon, the in-process engine and a client merging daemons' replies agree:
names in, rows out.
"""

from __future__ import annotations

import bisect
from collections.abc import Sequence
from typing import Protocol, TypeVar

from protocol.control import ListRequest
from protocol.errors import ErrorCode, FleetError
from protocol.names import check_name

#: The most robots one page may ask for (a page of them is ~40 MB of MessagePack).
MAX_LIMIT = 50_000
#: Names asked for up to this many are found by scanning the name lists, more by a dict.
_SCANNED = 16


def check(request: ListRequest) -> None:
    """Raise the protocol's error for a request no daemon can answer: a negative or huge
    ``limit``, more than ``MAX_LIMIT`` names, a malformed name in ``names`` or ``after``."""
    if not 0 <= request.limit <= MAX_LIMIT:
        raise FleetError(ErrorCode.INVALID_VALUE, f"limit must be 0 (all) to {MAX_LIMIT}, not {request.limit}", "limit")
    if len(request.names) > MAX_LIMIT:
        message = f"at most {MAX_LIMIT} names a request, not {len(request.names)}: ask for a page instead"
        raise FleetError(ErrorCode.INVALID_VALUE, message, "names")
    for name in request.names:
        check_name(name, "names")
    if request.after:
        check_name(request.after, "after")


def paged(request: ListRequest) -> bool:
    """Whether the answer is a page in name order (else: spawn order)."""
    return request.limit > 0 or bool(request.after)


def whole(request: ListRequest) -> bool:
    """Whether the request asks for every robot in spawn order (the list as it always was)."""
    return not (request.names or paged(request))


class NameIndex:
    """The rows of a fleet's robots by name and namespace, and their order by name: made once
    for a fleet, asked many times. Each part is made when first needed: a few names are found
    by a scan of the name lists in C (~0.3 ms at 20 000 robots), many by a dict, and the order
    by name (a few ms) only for a page."""

    def __init__(self, names: Sequence[str], namespaces: Sequence[str]) -> None:
        self._names = names  # (never changed while an index of them lives)
        self._namespaces = namespaces
        self._row_of: dict[str, int] | None = None
        self._order: tuple[list[int], list[str]] | None = None  # rows by name, and their names

    def _rows_of(self, keys: Sequence[str]) -> list[int]:
        """The rows of these names or namespaces, in spawn order, once each."""
        if len(keys) <= _SCANNED:
            found = [find_row(self._names, self._namespaces, key) for key in keys]
        else:
            row_of = self._row_of
            if row_of is None:  # made whole before it is shared: other threads may ask at once
                row_of = {ns: k for k, ns in enumerate(self._namespaces)}
                row_of.update((name, k) for k, name in enumerate(self._names))
                self._row_of = row_of
            found = [row_of.get(key) for key in keys]
        return sorted({k for k in found if k is not None})

    @property
    def _by_name(self) -> list[int]:
        return self._sorted_order()[0]

    @property
    def _sorted(self) -> list[str]:
        return self._sorted_order()[1]

    def _sorted_order(self) -> tuple[list[int], list[str]]:
        if self._order is None:
            names = self._names
            rows = sorted(range(len(names)), key=names.__getitem__)
            self._order = (rows, [names[k] for k in rows])
        return self._order

    def rows(self, request: ListRequest) -> list[int]:
        """The rows the request asks for, in the order of the answer (call :func:`check`
        first). Names of no robot are left out: a list says what there is."""
        if whole(request):
            return list(range(len(self._names)))
        if not request.names:
            start = bisect.bisect_right(self._sorted, request.after) if request.after else 0
            end = start + request.limit if request.limit else len(self._sorted)
            return self._by_name[start:end]
        wanted = self._rows_of(request.names)
        if not paged(request):
            return wanted
        names = self._names
        picked = [k for k in sorted(wanted, key=names.__getitem__) if names[k] > request.after]
        return picked[: request.limit] if request.limit else picked


def find_row(names: Sequence[str], namespaces: Sequence[str], key: str) -> int | None:
    """The row of the robot with this name or namespace, or None: a scan of the name lists in C
    (~0.3 ms at 20 000 robots, where a dict of them built for each new fleet took ~10)."""
    for listed in (names, namespaces):
        try:
            return listed.index(key)
        except ValueError:
            pass
    return None


class Named(Protocol):
    """A robot as a list has it: a record, or the simulation's state of it."""

    @property
    def name(self) -> str: ...

    @property
    def namespace(self) -> str: ...


N = TypeVar("N", bound=Named)


def select(robots: list[N], request: ListRequest) -> list[N]:
    """The robots the request asks for among ``robots`` (in spawn order, or several daemons'
    merged), in the order of the answer: what the in-process engine answers, and what a client
    applies to what it got, so that a daemon older than these fields (it answers every robot)
    gives the right answer too."""
    if whole(request):
        return robots
    index = NameIndex([r.name for r in robots], [r.namespace for r in robots])
    return [robots[k] for k in index.rows(request)]
