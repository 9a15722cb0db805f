"""Whether the light varies near the patches the camera sees: what Suzuki et al.'s solve learns R' from.

Suzuki, Mukaigawa & Yagi §3.3 solve l ≈ W r (eq. 34-35) for the profile
R'_1 … R'_n level by level.  Row j of W is Σ_k c_k A_k w_jk: when the light
is the same on every patch near j, W_j is c times the patch area at each
distance from j, the same for every such row away from the surface's rim, so
the near levels' columns are nearly proportional and only their sum is seen.
What separates them are rows where the light changes nearby (a shadow edge,
the rim of a spot or a stripe: the paper's pyramid has one lit face beside
three dark ones) and rows in the dark, which see the light only from a
distance.  Under nearly uniform light only where the surface ends (its rim,
its shape) varies the exitance; the monotone solve then absorbs eq. 28's
quantisation error into the ill-determined near levels, and eq. 36 is biased
beyond its interval.

A visible patch is **evenly lit** when the irradiance c_k of eq. 16 of its
``EVEN_NEIGHBOURS`` = 32 nearest patch centres (itself included: a disk of
about three patch spacings on a regular mesh) is > 0 and within
``EVEN_CONTRAST`` = 2 : 1 (min c > max c / 2).  A scene with fewer than
``UNEVEN_ROWS`` = 30 visible patches that are not evenly lit is under nearly
uniform light for the solve; a scene that shows fewer than 30 patches at all
is when any of them is evenly lit (until 2026-12-08 it always was: 25 patches
seen, every one beside a shadow edge, were refused as under uniform light).  Measured (2026-12-08, ``plate_scene``,
``pyramid_scene`` and ``face_site_scene`` of
:mod:`facestats.acquire.synthetic.scenes`): every visible patch is evenly lit
on the 40 mm plate lit all over by a point light 300 mm above (irradiance
within 1.3 %; 7,200 patches at ``spacing=1``) and on the pyramid lit from
above (four faces alike, 3,136 patches at 1.8 mm); not evenly lit are 6,988
of the plate's 7,200 patches under a 1° spot (394 lit), 3,842 under a
half-plane stripe, 2,566 of 3,136 on the pyramid of Suzuki Table 3 (one face
lit), 958 of 1,600 on the pyramid lit obliquely (three faces unequally), and
6,710-6,884 of 7,200 on the contactless cheek and forehead windows.  Before
this check, ``facestats translucency`` on the evenly lit plate (rendered with
the point kernel of eq. 17 as in *Making inputs* of
docs/translucency_from_image.md) found the fit range
(:func:`facestats.model.fitting.quantisation_choice.fit_distance`) collapsed
at every width up to the patch spacing, went on to twice it (0.63 mm) and
printed σ's = 2.15 [1.77, 2.63] mm⁻¹ with σa at the grid's edge for a truth
of (2.19, 0.0021) (a walkthrough's rendering of the same scene: 1.57 [1.53,
1.61]; the estimate is unstable there); under the 1° spot it prints
(2.19, 0.0021).
"""

from __future__ import annotations

import numpy as np

from facestats.core.validate import as_finite, check_shape
from facestats.errors import ValidationError

__all__ = ["EVEN_NEIGHBOURS", "EVEN_CONTRAST", "UNEVEN_ROWS", "evenly_lit_rows"]

#: Nearest patch centres (the patch itself included) over which a visible patch's light is compared.
EVEN_NEIGHBOURS = 32
#: Irradiance ratio (max / min among those neighbours) below which a visible patch is evenly lit.
EVEN_CONTRAST = 2.0
#: Fewer visible patches than this not evenly lit (all of them, when fewer are seen): the light is nearly uniform for
#: the solve (module docstring).
UNEVEN_ROWS = 30
#: Visible patches per block of the neighbour query (bounds memory to block × neighbours × 16 bytes).
_BLOCK = 16384


def evenly_lit_rows(points, irradiance, rows) -> np.ndarray:
    """Which visible patches are evenly lit (module docstring), shape (len(rows),).

    Parameters
    ----------
    points : array_like, shape (m, 3)
        Patch centres, mm.
    irradiance : array_like, shape (m,)
        c_k of Suzuki eq. 16 per patch (≥ 0, per unit area: not multiplied by the patch area, whose variation is
        not the light's).
    rows : array_like of int
        Indices of the visible patches.

    Returns
    -------
    ndarray of bool
        True where the irradiance of the row's ``EVEN_NEIGHBOURS`` nearest patches is > 0 and within
        ``EVEN_CONTRAST`` : 1.
    """
    from scipy.spatial import cKDTree

    p = check_shape(as_finite(points, "points", dtype=np.float64), "points", (None, 3))
    c = check_shape(as_finite(irradiance, "irradiance", 0, None, dtype=np.float64), "irradiance", (p.shape[0],))
    idx = np.asarray(rows)
    if idx.ndim != 1 or (idx.size and (idx.dtype.kind not in "iu" or idx.min() < 0 or idx.max() >= p.shape[0])):
        raise ValidationError(f"rows must be a 1-D array of patch indices in [0, {p.shape[0]}), got {idx!r}")
    tree = cKDTree(p)
    k = min(EVEN_NEIGHBOURS, p.shape[0])
    out = np.zeros(idx.size, bool)
    for start in range(0, idx.size, _BLOCK):  # loop over blocks of rows, vectorised within a block
        near = tree.query(p[idx[start : start + _BLOCK]], k=k)[1].reshape(-1, k)
        cn = c[near]
        out[start : start + _BLOCK] = cn.min(axis=1) * EVEN_CONTRAST > cn.max(axis=1)
    return out
