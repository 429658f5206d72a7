"""The shared argument checks of aeroid._value_checks."""

from __future__ import annotations

import pytest

from aeroid._value_checks import check_choice
from aeroid.errors import IdentificationError


def test_check_choice_passes_a_member_and_names_the_option_of_another():
    check_choice("ls", "method", ("ls", "ml"), IdentificationError)
    with pytest.raises(IdentificationError) as err:
        check_choice("LS", "method", ("ls", "ml"), IdentificationError)
    assert str(err.value) == "method 'LS' is unknown; choose one of ['ls', 'ml']"


def test_check_choice_lists_a_mapping_by_its_keys():
    with pytest.raises(KeyError, match=r"weighting None is unknown; choose one of \['a', 'b'\]"):
        check_choice(None, "weighting", {"a": 1, "b": 2}, KeyError)
