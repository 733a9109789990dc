"""The one comma-list parser (`aquarium_warp.arguments.parse_list`) of `bench`, `study` and the
benchmark scripts: what each list means, and that every malformed list is refused with its name."""

from __future__ import annotations

import pytest

from aquarium_warp.arguments import parse_list
from aquarium_warp.bench import parse_counts

# (text, kind, last, expected)
PARSED = [
    ("4,8,16", int, "exact", [4, 8, 16]),
    (" 4 , 8 ,16,", int, "exact", [4, 8, 16]),
    ("120, 240", float, "exact", [120.0, 240.0]),
    ("2.5", float, "exact", [2.5]),
    ("-10,0,...,30", float, "exact", [-10.0, 0.0, 10.0, 20.0, 30.0]),
    ("4,8,...,64", int, "exact", [4, 8, 16, 32, 64]),
    ("30,60,...,180", float, "exact", [30.0, 60.0, 90.0, 120.0, 150.0, 180.0]),
    ("2,4,...,10", int, "exact", [2, 4, 6, 8, 10]),  # the ratio misses 10, the step reaches it
    ("2,4,...,16", int, "exact", [2, 4, 8, 16]),  # both would: the ratio comes first
    ("100,200,300,...,500", int, "exact", [100, 200, 300, 400, 500]),
    ("1,2,4,...,64", int, "exact", [1, 2, 4, 8, 16, 32, 64]),
    ("16,64,...,1000000", int, "cap", [16, 64, 256, 1024, 4096, 16384, 65536, 262144, 1000000]),
    ("100,200,...,500", int, "cap", [100, 200, 400, 500]),
    ("2,3,...,10", int, "cap", [2, 3, 4, 6, 9, 10]),  # ratio 1.5, rounded
    ("4,8,...,8.5", float, "cap", [4.0, 8.0, 8.5]),
    ([3, 5], int, "cap", [3, 5]),
    ((3.0, 5), int, "exact", [3, 5]),
]

# (text, kind, last, words of the error)
REFUSED = [
    ("", int, "exact", "is empty"),
    (" , ", int, "exact", "is empty"),
    ("a,b", int, "exact", "comma-separated list of integers"),
    ("4,x", float, "exact", "comma-separated list of numbers"),
    ("2.5", int, "exact", "list of integers"),
    ("nan", float, "exact", "list of numbers"),
    ("inf,1", float, "exact", "list of numbers"),
    ("4,...", int, "exact", "at least two terms"),
    ("1,...,9", int, "cap", "at least two terms"),
    ("4,...,8,16", int, "exact", "at least two terms"),
    ("4,8,...,...,16", int, "exact", "at least two terms"),
    ("8,4,...,1", int, "exact", "increase"),
    ("16,8,...,2", int, "cap", "increase"),
    ("4,8,...,8", int, "exact", "increase"),
    ("16,64,...,20", int, "cap", "increase"),
    ("4,8,...,99", int, "exact", "constant ratio or step that reaches 99"),
    ("1,2,5,...,64", int, "exact", "constant ratio or step"),
    ("1,2,5,...,64", int, "cap", "constant ratio or step"),
    ([2.5], int, "cap", "list of integers"),
    ([True], int, "cap", "list of integers"),
    (["4", None], int, "cap", "list of integers"),
]


@pytest.mark.parametrize(("text", "kind", "last", "expected"), PARSED, ids=[repr(p[0]) for p in PARSED])
def test_parses(text, kind, last, expected):
    values = parse_list(text, kind, "--x", last=last)
    assert values == expected
    assert all(type(v) is kind for v in values)


@pytest.mark.parametrize(("text", "kind", "last", "words"), REFUSED, ids=[repr(r[0]) for r in REFUSED])
def test_refuses_with_the_option_name(text, kind, last, words):
    with pytest.raises(ValueError, match="--x") as error:
        parse_list(text, kind, "--x", last=last)
    assert words in str(error.value)


@pytest.mark.parametrize("text", ["0,4", "4,0", [0], "-4,-2,...,8"])
def test_minimum(text):
    with pytest.raises(ValueError, match=r"--x=.*every value must be >= 1"):
        parse_list(text, int, "--x", last="cap", minimum=1)


def test_bench_counts_are_positive_integers_ending_at_the_last_term():
    assert parse_counts("1,16,...,65536") == [1, 16, 256, 4096, 65536]
    assert parse_counts("16,64,...,100000")[-2:] == [65536, 100000]
    with pytest.raises(ValueError, match="agents="):
        parse_counts("0,4", "agents")
