"""The argparse types and value checks of `aquarium_warp.arguments` (the lists have test_argument_lists.py):
each accepts its range and refuses the rest in one line that names the value or parameter and the range."""

from __future__ import annotations

import argparse
import math

import pytest

from aquarium_warp.arguments import (
    check_int,
    check_number,
    int_at_least,
    non_negative_float,
    non_negative_int,
    number,
    positive_float,
    positive_int,
)


def test_integer_types_take_any_size_at_or_above_their_bound():
    assert positive_int("1") == 1 and non_negative_int("0") == 0 and int_at_least(2)("2") == 2
    assert non_negative_int(str(2**70)) == 2**70
    for parse, text in (
        (positive_int, "0"),
        (non_negative_int, "-1"),
        (int_at_least(2), "1"),
        (positive_int, "1.5"),
        (positive_int, "x"),
    ):
        with pytest.raises(argparse.ArgumentTypeError, match=f"invalid value '{text}': must be an integer >= "):
            parse(text)


def test_number_types_refuse_nan_infinity_and_out_of_range():
    assert positive_float("0.25") == 0.25 and non_negative_float("0") == 0.0
    for parse, text, allowed in (
        (positive_float, "0", "> 0"),
        (positive_float, "inf", "> 0"),
        (non_negative_float, "-0.1", ">= 0"),
        (non_negative_float, "nan", ">= 0"),
        (positive_float, "x", "> 0"),
    ):
        with pytest.raises(argparse.ArgumentTypeError, match=f"'{text}': must be a finite number {allowed}"):
            parse(text)
    half = number("a number in [0, 0.5]", lambda v: 0 <= v <= 0.5)
    assert half("0.5") == 0.5
    with pytest.raises(argparse.ArgumentTypeError, match=r"must be a number in \[0, 0.5\]"):
        half("nan")


def test_value_checks_name_the_parameter_and_range():
    check_int("seeds", 1)
    check_int("steps", 2, 2)
    for value in (0, 1.0, True, "3"):
        with pytest.raises(ValueError, match=r"^seeds=.* must be an integer >= 1$"):
            check_int("seeds", value)
    check_number("flee-angle", 180, 0.0, 180.0)
    for value in (-1e-9, 180.5, math.nan, math.inf, False, "1"):
        with pytest.raises(ValueError, match=r"^flee-angle=.* must be a finite number in \[0, 180\]$"):
            check_number("flee-angle", value, 0.0, 180.0)
