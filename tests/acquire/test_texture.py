"""The synthetic albedo texture: spots of physical size darken the face by the same amount at any map size."""

import numpy as np

from facestats.acquire.synthetic.texture import albedo_map


def test_spot_darkening_is_physical_and_independent_of_the_texel_size():
    """A 120 mm square of forehead (region 2: freckles allowed, no tint) with freckles and three moles, drawn with
    10 mm, 5 mm and 0.5 mm texels: the mean albedo over 48 draws is the base colour times one minus the spots'
    area coverage, computed from the module's densities (pores 5 per cm², 0.3 mm, strength U(0.03, 0.08);
    freckles 2 per cm², 1 mm, U(0.15, 0.35), channel weights 0.45 / 0.75 / 0.85; moles 2 mm, U(0.5, 0.8),
    0.6 / 0.75 / 0.8) and the integral 2π r² of a Gaussian spot of σ = r.  The standard error of the 48-draw mean
    is 0.004 (the low-frequency tint noise); with 10 mm texels the old scaling gave 0.67 in R (pores and freckles
    narrower than a texel each removed 0.77 × strength texels), with 5 mm texels about 0.9."""
    base = np.array([0.5, 0.3, 0.2])
    side_mm = 120.0
    area = side_mm**2
    pores = 0.05 * 0.055 * 2 * np.pi * 0.3**2
    freckles = 0.02 * 0.25 * 2 * np.pi * 1.0**2 * np.array([0.45, 0.75, 0.85])
    moles = 3 * 0.65 * 2 * np.pi * 2.0**2 / area * np.array([0.6, 0.75, 0.8])
    expected = 1 - pores - freckles - moles
    for n in (12, 24, 240):
        region = np.full((n, n), 2, np.uint8)
        ratios = [
            albedo_map(region, base, np.random.default_rng(seed), texel_mm=side_mm / n, freckles=True, moles=3)
            .reshape(-1, 3)
            .mean(0)
            / base
            for seed in range(48)
        ]
        np.testing.assert_allclose(np.mean(ratios, 0), expected, atol=0.012, err_msg=f"{n} texels")
