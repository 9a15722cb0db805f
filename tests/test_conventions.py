"""``facestats.core.conventions``: the parsers of skin types, regions and ages refuse what is not one.

Booleans are ints to Python (``int(True) == 1``): ``parse_skin_type(True)`` and ``parse_region(True)`` gave 1,
whereas :func:`facestats.core.validate.check_integer` refuses a flag.  ``age_group(29.5)`` said "age must be in
0-200 years" of an age inside that range: ages are whole years, and the message now says so.
"""

import numpy as np
import pytest

from facestats.core.conventions import age_group, parse_age, parse_region, parse_skin_type, skin_type_label
from facestats.errors import ValidationError


@pytest.mark.parametrize("flag", [True, False, np.True_, np.bool_(False)])
def test_skin_type_and_region_refuse_booleans(flag):
    with pytest.raises(ValidationError, match="skin type must be I-VI or 1-6, got the boolean"):
        parse_skin_type(flag)
    with pytest.raises(ValidationError, match="region must be 1-10 or a region name, got the boolean"):
        parse_region(flag)


def test_skin_type_and_region_still_take_numbers_and_names():
    assert parse_skin_type(3) == parse_skin_type(3.0) == parse_skin_type(np.int64(3)) == parse_skin_type("iii") == 3
    assert parse_region(1) == parse_region(np.int32(1)) == parse_region("1") == parse_region("mustache") == 1


def test_age_group_refuses_a_fractional_age_saying_ages_are_whole_years():
    for bad in (29.5, 39.9, float("nan"), True, np.True_, "30"):
        with pytest.raises(ValidationError, match="age must be a whole number of years"):
            age_group(bad)
    with pytest.raises(ValidationError, match="age must be in 0-200 years, got 201"):
        age_group(201)
    assert [age_group(a) for a in (0, 29, 30.0, np.int64(49), 50, 200)] == ["20s", "20s", "30s", "40s", "50s+", "50s+"]


def test_age_range_refuses_numpy_booleans():
    with pytest.raises(ValidationError, match="age range must be two ages"):
        parse_age((np.True_, 30))
    assert parse_age((np.int64(20), 30.0)) == (20, 30)


def test_skin_type_label_names_the_pooled_group_i_ii():
    """Pooled types I and II are coded 2; the CCA legend and posterior_population.json called that group 'II'."""
    assert [skin_type_label(t, grouped_i_ii=True) for t in (2, 3, 6)] == ["I-II", "III", "VI"]
    assert [skin_type_label(t) for t in (1, 2, "iv")] == ["I", "II", "IV"]
    with pytest.raises(ValidationError, match="skin type must be I-VI or 1-6, got 7"):
        skin_type_label(7, grouped_i_ii=True)
