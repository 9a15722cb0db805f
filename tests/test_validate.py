"""``facestats.core.validate.as_scalar`` and the functions that take one number through it.

A red team passed one-element arrays where a number was expected: ``float()`` of them raised a bare
``TypeError`` ("only 0-dimensional arrays can be converted"); each is now a ValidationError naming the argument.
"""

import numpy as np
import pytest

from facestats.core.validate import as_scalar
from facestats.edit import Histogram, max_levels
from facestats.errors import ValidationError
from facestats.model import skin
from facestats.model.microstructure import kernel_taps
from facestats.model.sphere import rotation_y


def test_as_scalar_takes_one_number_and_names_anything_else():
    assert as_scalar(np.float32(0.5), "x") == 0.5 and isinstance(as_scalar(np.array(2), "x"), float)
    assert as_scalar(3, "x", 0, 4) == 3.0
    for bad, message in (([0.5], r"x must be one number, got an array of shape \(1,\)"), (np.nan, "x must be finite"),
                         ("a", "x must be numeric"), (5.0, r"x must lie in \[0, 4\]")):  # fmt: skip
        with pytest.raises(ValidationError, match=message):
            as_scalar(bad, "x", 0, 4)


@pytest.mark.parametrize(
    "call, name",
    [
        (lambda: kernel_taps(np.array([0.5]), 10.0, 1.0), "alpha"),
        (lambda: kernel_taps(0.5, [10.0], 1.0), "sigma_um"),
        (lambda: rotation_y(np.array([0.5])), "angle"),
        (lambda: skin.neighbour_pairs(np.zeros((3, 3)), np.array([1.0, 2.0])), "radius"),
    ],
)
def test_one_element_arrays_where_a_number_is_expected_are_named(call, name):
    with pytest.raises(ValidationError, match=rf"{name} must be one number, got an array of shape"):
        call()


def test_per_channel_arguments_and_ranges_of_the_wrong_length_are_named():
    with pytest.raises(ValidationError, match=r"sigma_s_prime must be one value or one per channel, shape \(3,\)"):
        skin.SubsurfaceTransport([1.0, 1.0], [0.1, 0.1])
    with pytest.raises(ValidationError, match="eta must be one number"):
        skin.SubsurfaceTransport([1.0, 1.0, 1.0], [0.1, 0.1, 0.1], eta=[1.3, 1.4])
    assert max_levels((0, 8)) == 0 and max_levels((512, 512)) == 7  # was "math domain error" for an empty side
    with pytest.raises(ValidationError, match=r"range must be \(low, high\)"):
        Histogram.from_data(np.linspace(0, 1, 10), bins=4, range=(1,))
    with pytest.raises(ValidationError, match="range must be finite"):
        Histogram.from_data(np.linspace(0, 1, 10), bins=4, range=(0, np.inf))
