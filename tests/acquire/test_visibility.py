"""Shadow maps as a surface test: what a camera pixel's ray meets (an e2e red team: taps beyond a silhouette)."""

import numpy as np
import pytest

from facestats.acquire.visibility import ShadowMaps
from facestats.errors import ValidationError


def _plate(x0, x1, y0, y1, z):
    verts = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], float)
    return verts, np.array([[0, 1, 2], [0, 2, 3]])


def _scene():
    """A 100 mm plate at z = 0 seen from 1 m above, a 20 mm plate 20 mm over it at x = 30 mm."""
    (v0, f0), (v1, f1) = _plate(-50, 50, -50, 50, 0.0), _plate(20, 40, -10, 10, 20.0)
    maps = ShadowMaps(np.vstack([v0, v1]), np.vstack([f0, f1 + 4]), [[0.0, 0.0, 1000.0]], resolution=256)
    return maps


def test_on_surface_tells_the_background_and_occluders_from_the_surface():
    maps = _scene()
    points = np.array([[0, 0, 0], [-30, 20, 0], [49, 0, 0], [56, 0, 0], [0, -70, 0], [30, 0, 0], [30, 0, 20]], float)
    normals = np.tile([0.0, 0.0, 1.0], (len(points), 1))
    on = maps.on_surface(points, normals, 0)
    seen = maps.visible(points, normals)[:, 0]
    # on the plate, at its edge, beyond it (twice), under the small plate, on the small plate
    np.testing.assert_array_equal(on, [True, True, True, False, False, False, True])
    np.testing.assert_array_equal(seen, [True, True, True, True, True, False, True])  # beyond: nothing occludes it
    assert not maps.on_surface(points[:1], -normals[:1], 0)[0]  # a back face is not seen
    with pytest.raises(ValidationError, match="viewpoint"):
        maps.on_surface(points, normals, 1)
