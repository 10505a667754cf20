"""Tests of ``mcdenoise_cli.parsing``: option text -> library values, bad text named by option."""

from __future__ import annotations

import doctest

import pytest
from mcdenoise_cli import parsing
from mcdenoise_cli.parsing import parse_res, parse_shard, parse_spp

from mcdenoise.render.config import RenderError


def test_parsers_accept_good_and_refuse_bad_values() -> None:
    assert parse_spp("4,16,64") == (4, 16, 64)
    assert parse_shard("2/3") == (2, 3)
    assert parse_res("256") == (256, 256) and parse_res("320x200") == (320, 200)
    for bad in ("0", "16,4", "4,4", "a,b", ""):
        with pytest.raises(RenderError, match="--spp"):
            parse_spp(bad)
    for bad in ("3/2", "0/2", "1/0", "1-2", "x"):
        with pytest.raises(RenderError, match="shard"):
            parse_shard(bad)
    for bad in ("0", "10x0", "abc"):
        with pytest.raises(RenderError, match="--res"):
            parse_res(bad)


def test_docstring_examples() -> None:
    failed, attempted = doctest.testmod(parsing, optionflags=doctest.ELLIPSIS)
    assert attempted > 0 and failed == 0
