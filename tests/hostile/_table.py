"""The one pytest body of every hostile table: `outcomes` runs a module's CASES (each in its
own process, see `_hostile_driver`) and `test_case` checks one of them."""

from __future__ import annotations

import os

import pytest
from _hostile_driver import check, ids, run_cases


def table(cases, setup=None):
    """`(fixture, test)` for a module's table: assign them to `outcomes` and
    `test_hostile_input` in the test module."""

    @pytest.fixture(scope="module")
    def outcomes(tmp_path_factory):
        if not hasattr(os, "fork"):
            pytest.skip("needs os.fork")
        kwargs = {} if setup is None else {"setup": setup}
        return run_cases(cases, tmp_path_factory.mktemp("hostile"), **kwargs)

    @pytest.mark.parametrize("case", range(len(cases)), ids=ids(cases))
    def test_hostile_input(outcomes, case):
        check(cases[case], outcomes[case])

    test_hostile_input.setup = setup  # read by test_coverage (the names its aliases call)
    return outcomes, test_hostile_input
