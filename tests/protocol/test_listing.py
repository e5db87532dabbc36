"""Which robots a list request names, against the rules written out plainly (protocol/listing.py)."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.control import ListRequest, Pose2D, RobotList, RobotRecord
from protocol.errors import ErrorCode, FleetError
from protocol.gather import merge_lists
from protocol.listing import MAX_LIMIT, NameIndex, check, paged, select, whole
from protocol.messages import Time

NAMES = st.lists(st.from_regex(r"[a-d][a-d0-9_]{0,3}", fullmatch=True), unique=True, max_size=30)


def _fleet(names: list[str]) -> tuple[list[str], list[str]]:
    """Names, and namespaces that differ from them (``ns_`` + name) for every other robot."""
    return names, [f"ns_{n}" if k % 2 else n for k, n in enumerate(names)]


def _expected(names: list[str], namespaces: list[str], request: ListRequest) -> list[int]:
    """The rows the protocol's words ask for, worked out the slow, obvious way."""
    rows = list(range(len(names)))
    if request.names:
        rows = [k for k in rows if names[k] in request.names or namespaces[k] in request.names]
    if not paged(request):
        return rows
    rows = sorted((k for k in rows if names[k] > request.after), key=lambda k: names[k])
    return rows[: request.limit] if request.limit else rows


@settings(max_examples=300, deadline=None)
@given(NAMES, st.data())
def test_the_rows_are_the_ones_the_request_names(names: list[str], data: st.DataObject) -> None:
    names, namespaces = _fleet(names)
    some = st.sampled_from(names + namespaces + ["zz", "a"]) if names else st.just("zz")
    request = ListRequest(
        names=data.draw(st.lists(some, max_size=24)),  # a few are scanned for, many looked up
        after=data.draw(st.one_of(st.just(""), some)),
        limit=data.draw(st.integers(0, 8)),
    )
    assert NameIndex(names, namespaces).rows(request) == _expected(names, namespaces, request)


@settings(max_examples=100, deadline=None)
@given(NAMES, st.integers(1, 7))
def test_pages_read_one_after_another_give_every_robot_once_in_name_order(names: list[str], limit: int) -> None:
    names, namespaces = _fleet(names)
    index = NameIndex(names, namespaces)
    seen: list[str] = []
    after = ""
    while True:
        page = [names[k] for k in index.rows(ListRequest(after=after, limit=limit))]
        seen += page
        if len(page) < limit:
            break
        after = page[-1]
    assert seen == sorted(names)


def test_the_next_page_is_right_when_the_last_robot_seen_was_deleted_meanwhile() -> None:
    before = NameIndex(["a", "b", "c", "d"], ["a", "b", "c", "d"])
    first = before.rows(ListRequest(limit=2))
    assert first == [0, 1]
    after_delete = NameIndex(["a", "c", "d"], ["a", "c", "d"])  # b went
    assert after_delete.rows(ListRequest(after="b", limit=2)) == [1, 2]


def test_an_empty_request_is_the_whole_list_in_spawn_order() -> None:
    index = NameIndex(["c", "a", "b"], ["c", "a", "b"])
    assert whole(ListRequest())
    assert index.rows(ListRequest()) == [0, 1, 2]
    assert index.rows(ListRequest(names=["b", "c"])) == [0, 2]  # spawn order


@pytest.mark.parametrize(
    ("request_", "code", "field"),
    [
        (ListRequest(limit=-1), ErrorCode.INVALID_VALUE, "limit"),
        (ListRequest(limit=MAX_LIMIT + 1), ErrorCode.INVALID_VALUE, "limit"),
        (ListRequest(names=["tb3_0", "no spaces"]), ErrorCode.INVALID_NAME, "names"),
        (ListRequest(names=[""]), ErrorCode.INVALID_NAME, "names"),
        (ListRequest(after="a/b"), ErrorCode.INVALID_NAME, "after"),
    ],
)
def test_a_request_no_daemon_can_answer_is_refused_saying_which_field(
    request_: ListRequest, code: ErrorCode, field: str
) -> None:
    with pytest.raises(FleetError) as e:
        check(request_)
    assert e.value.code == code and e.value.field == field


def _list(*names: str) -> RobotList:
    robots = [RobotRecord(name=n, namespace=n, model="burger", pose=Pose2D()) for n in names]
    return RobotList(stamp=Time(sec=1, nanosec=0), robots=robots)


def test_several_daemons_pages_merge_into_the_fleets_page() -> None:
    # each daemon gave its own first three after "": the fleet's first three
    page = ListRequest(limit=3)
    merged = merge_lists([_list("a", "d", "e"), _list("b", "c", "f")]).robots
    assert [r.name for r in select(merged, page)] == ["a", "b", "c"]


@pytest.mark.parametrize(
    ("request_", "want"),
    [
        (ListRequest(names=["r_d", "r_a", "nobody"]), ["r_a", "r_d"]),
        (ListRequest(limit=2), ["r_a", "r_b"]),
        (ListRequest(after="r_b", limit=2), ["r_c", "r_d"]),
        (ListRequest(after="r_d", limit=2), ["r_e"]),
        (ListRequest(names=["r_e", "r_b", "r_c"], after="r_b", limit=1), ["r_c"]),
    ],
)
def test_a_daemon_that_answers_every_robot_still_gives_the_client_what_it_asked(
    request_: ListRequest, want: list[str]
) -> None:
    """A daemon older than these fields ignores them and lists everyone (spawn order), alone or
    beside a new one: the client picks the answer out of what came."""
    alone = _list("r_c", "r_a", "r_e", "r_b", "r_d")
    assert [r.name for r in select(merge_lists([alone]).robots, request_)] == want
    old = _list("r_c", "r_a", "r_e")  # beside a new daemon that has r_b and r_d and answers for them
    new = _list(*(r.name for r in select(_list("r_b", "r_d").robots, request_)))
    assert [r.name for r in select(merge_lists([old, new]).robots, request_)] == want
