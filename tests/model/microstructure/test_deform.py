"""Normals of a deformed microstructure map: the chain rule of the deform module (Nagano et al. 2015 §5)."""

import numpy as np
from scipy.spatial.transform import Rotation

from facestats.face.geometry import grid_triangles
from facestats.model.microstructure.deform import normal_jacobian
from facestats.model.strain import MeshStrain


def test_slope_of_a_height_ramp_on_a_sheared_plane_is_the_chain_rule_through_world_coordinates():
    """A flat sheet (50 x 20 mm, u = x / 100, v = y / 40) on a non-square map (64 rows, 128 columns) carries heights
    h = a p_u + b p_v um (p in texels).  At rest ∇_x h = (a W / 100, b H / 40) um per mm; sheared in its plane by a
    non-symmetric A (then moved rigidly), ∇_x' h = A⁻ᵀ ∇_x h.  The slope the jacobian gives is that gradient / 1000
    (um over mm) in the deformed tangent frame: the frame may be rotated, its length may not.  (With an anisotropic
    UV map T = M'⁻¹ M is not symmetric, so T⁻ᵀ and T⁻¹ differ.)"""
    n = 12
    x, y = np.meshgrid(np.linspace(0, 50.0, n), np.linspace(0, 20.0, n))
    rest = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], 1)
    uv = np.stack([x.ravel() / 100 + 0.2, y.ravel() / 40 + 0.2], 1)
    shear = np.array([[1.2, 0.3], [-0.1, 0.9]])
    a3 = np.eye(3)
    a3[:2, :2] = shear
    rot = Rotation.from_euler("xyz", [20, -35, 50], degrees=True).as_matrix()
    deformed = rest @ a3.T @ rot.T + 3.0
    height, width = 64, 128
    strain = MeshStrain(rest, grid_triangles(np.ones((n, n), bool)), uv).texels_strain(deformed, (height, width))
    ok = strain.valid
    assert ok.sum() > 1000
    for a, b in ((1.0, 0.0), (0.0, 1.0), (0.7, -1.3)):
        grad_rest = np.array([a * width / 100.0, b * height / 40.0])  # um per mm
        for deformed_frame, grad in ((False, grad_rest), (True, np.linalg.inv(shear).T @ grad_rest)):
            jac = normal_jacobian(strain, deformed=deformed_frame)[ok]
            g = jac @ np.array([a, b])
            assert np.abs(np.linalg.norm(g, axis=-1) - np.linalg.norm(grad) / 1000.0).max() < 1e-9, (a, b)


def test_a_stretch_along_u_convolves_rows_with_the_kernel_of_the_texel_size_along_u():
    """A 0.5 x 0.4 mm sheet, 1 UV = 1 mm, on 64 rows x 128 columns: texels of 7.8125 um along u, 15.625 um along v.
    Stretched by 1.2 along x (= u), the s kernel (eq. 8-9: alpha 0.618, sigma 19.34 um) is 2.48 texels wide along
    the rows, and the t kernel (r_t = 1) is the identity; away from the island's border each row is convolved by
    kernel_taps(alpha, sigma, 7.8125) (scipy's convolve1d as the reference)."""
    from scipy.ndimage import convolve1d

    from facestats.model.microstructure import deform_microstructure, kernel_parameters, kernel_taps

    n = 12
    x, y = np.meshgrid(np.linspace(0, 0.5, n), np.linspace(0, 0.4, n))
    rest = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], 1)
    uv = np.stack([x.ravel() + 0.2, y.ravel() + 0.3], 1)
    strain = MeshStrain(rest, grid_triangles(np.ones((n, n), bool)), uv).texels_strain(rest * [1.2, 1, 1], (64, 128))
    assert np.allclose(strain.texel_um_s[strain.valid], 1000 / 128) and np.allclose(strain.r_t[strain.valid], 1)
    neutral = np.random.default_rng(0).normal(size=(64, 128))
    out = deform_microstructure(neutral, strain, backend="numpy").displacement
    alpha, sigma = (float(v) for v in kernel_parameters(1.2))
    ref = convolve1d(neutral, kernel_taps(alpha, sigma, 1000 / 128), axis=1)
    assert np.abs(out - ref)[24:40, 40:75].max() < 1e-6  # alpha and sigma are float32 per texel
