"""Strain of a deforming mesh in texture space (Nagano et al. 2015 eq. 10-13)."""

import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from facestats.errors import FacestatsError
from facestats.face.geometry import grid_triangles
from facestats.model.strain import (
    MeshStrain,
    inv2x2,
    svd2x2,
    tangent_frames,
    texel_strain,
    triangle_strain,
    triangulate,
    vertex_strain,
)

ROT3 = Rotation.from_euler("xyz", [20, -35, 50], degrees=True).as_matrix()


def _plane(n=12, size=(50.0, 40.0)):
    x, y = np.meshgrid(np.linspace(0, size[0], n), np.linspace(0, size[1], n))
    v = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], 1)
    uv = np.stack([x.ravel() / 100 + 0.2, y.ravel() / 100 + 0.3], 1)  # 1 UV = 100 mm, u along x, v along y
    return v, grid_triangles(np.ones((n, n), bool)), uv


def _stretch(theta_deg, rs, rt):
    th = np.deg2rad(theta_deg)
    rot = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    a = np.eye(3)
    a[:2, :2] = rot @ np.diag([rs, rt]) @ rot.T
    return a


def _angle(axis):
    return np.degrees(np.arctan2(axis[..., 1], axis[..., 0])) % 180


def test_svd2x2_matches_numpy():
    a = np.random.default_rng(0).normal(size=(500, 2, 2))
    u, s, v = svd2x2(a)
    assert np.abs(u @ (s[..., None] * np.swapaxes(v, -1, -2)) - a).max() < 1e-13
    assert np.abs(np.abs(s) - np.linalg.svd(a, compute_uv=False)).max() < 1e-13
    assert np.all(s[:, 0] >= np.abs(s[:, 1]))


def test_inv2x2_matches_numpy_and_marks_singular_matrices_without_warnings():
    a = np.random.default_rng(1).normal(size=(7, 60, 2, 2))
    inv, det = inv2x2(a)
    assert inv.shape == a.shape and det.shape == a.shape[:-2]
    assert np.abs(inv - np.linalg.inv(a)).max() < 1e-9 * np.abs(np.linalg.inv(a)).max()
    assert np.abs(det - np.linalg.det(a)).max() < 1e-12
    assert np.abs(a @ inv - np.eye(2)).max() < 1e-9
    singular = np.array([[[1.0, 2.0], [2.0, 4.0]], [[0.0, 0.0], [0.0, 0.0]]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        inv, det = inv2x2(singular)
        huge, det_huge = inv2x2(1e155 * np.eye(2))  # beyond the documented range: det overflows, silently
    assert (det == 0).all() and not np.isfinite(inv).any()
    assert det_huge == np.inf and (huge == 0).all()


def test_tangent_frame_is_the_closest_rotation_of_the_uv_map():
    v, tri, uv = _plane(5)
    v = (v + np.random.default_rng(1).normal(0, 1.0, v.shape)) @ ROT3.T  # a bumpy, rotated sheet
    q, r, deg = tangent_frames(v, tri, uv[tri])
    assert not deg.any()
    for f in range(0, len(tri), 7):  # SVD of [Q; q1 x q2], the paper's recipe
        a = np.vstack([q[f], np.cross(q[f][0], q[f][1])])
        uu, _, vt = np.linalg.svd(a)
        assert np.abs((uu @ vt)[:2] - r[f]).max() < 1e-12


@pytest.mark.parametrize("level", ["triangle", "vertex", "texel"])
def test_known_stretch_and_rotation_is_recovered(level):
    v, tri, uv = _plane()
    deformed = (v @ _stretch(30, 1.2, 0.9).T) @ ROT3.T + np.array([3.0, 4.0, 5.0])
    if level == "triangle":
        st = triangle_strain(v, deformed, tri, uv)
        ok = st.valid
    elif level == "vertex":
        st = vertex_strain(v, deformed, tri, uv)
        ok = st.valid
    else:
        st = texel_strain(v, deformed, tri, uv, 64)
        ok = st.valid
        assert ok.sum() > 600
        # texel size along the axes: 1 UV = 100 mm over 64 texels
        assert np.abs(st.texel_um_s[ok] - 100e3 / 64).max() < 1e-6
    assert np.abs(st.r_s[ok] - 1.2).max() < 1e-12 and np.abs(st.r_t[ok] - 0.9).max() < 1e-12
    assert np.abs(_angle(st.axis_s[ok]) - 30).max() < 1e-9
    assert np.abs(_angle(st.axis_t[ok]) - 120).max() < 1e-9


def test_rigid_motion_has_no_strain_and_det_t_is_the_area_ratio():
    v, tri, uv = _plane(9)
    rng = np.random.default_rng(2)
    v = v + rng.normal(0, 0.8, v.shape)  # not planar
    st = triangle_strain(v, v @ ROT3.T - 7.0, tri, uv)
    assert np.abs(st.r_s - 1).max() < 1e-12 and np.abs(st.r_t - 1).max() < 1e-12
    deformed = v + rng.normal(0, 0.5, v.shape)
    st = triangle_strain(v, deformed, tri, uv)
    area = [
        0.5 * np.linalg.norm(np.cross(p[tri][:, 1] - p[tri][:, 0], p[tri][:, 2] - p[tri][:, 0]), axis=1)
        for p in (v, deformed)
    ]
    assert np.abs(st.area_ratio - area[1] / area[0]).max() < 1e-12
    assert np.abs(st.r_s * st.r_t - st.area_ratio).max() < 1e-12


def test_degenerate_triangles_are_masked_and_counted_never_nan():
    v, tri, uv = _plane(6)
    deformed = v.copy()
    deformed[tri[3]] = deformed[tri[3][0]]  # collapse a triangle (and its neighbours' corners move)
    uv2 = uv.copy()
    uv2[tri[10][1]] = uv2[tri[10][0]]  # zero UV area
    st = triangle_strain(v, deformed, tri, uv2)
    assert st.n_degenerate >= 2 and not st.valid[3] and not st.valid[10]
    assert np.all(np.isfinite(st.r_s)) and np.all(np.isfinite(st.axis_s)) and np.all(np.isfinite(st.t))
    # Orientation-blind (module docstring): a mirrored mesh has the strain of the original.
    st = triangle_strain(v, v * np.array([1.0, -1.0, 1.0]), tri, uv)
    assert np.abs(st.r_s - 1).max() < 1e-12 and st.valid.all()
    ts = texel_strain(v, deformed, tri, uv2, 32)
    assert np.all(np.isfinite(ts.r_s)) and np.all(np.isfinite(ts.texel_um_s))


def test_quads_are_split_and_a_window_is_a_crop_of_the_map():
    tri, src = triangulate(np.array([[0, 1, 2, 3], [4, 5, 6, 7]]))
    assert tri.tolist() == [[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]] and src.tolist() == [0, 0, 1, 1]
    v, t, uv = _plane(10)
    rng = np.random.default_rng(3)
    deformed = v + rng.normal(0, 0.6, v.shape)
    ms = MeshStrain(v, t, uv)
    full = ms.texels_strain(deformed, (96, 128))
    win = ms.texels_strain(deformed, (96, 128), window=(30, 40, 25, 33))
    crop = (slice(30, 55), slice(40, 73))
    for name in ("r_s", "r_t", "texel_um_s", "valid", "island"):
        assert np.allclose(getattr(win, name), getattr(full, name)[crop], rtol=0, atol=1e-12), name


def test_raster_refuses_a_bad_map_or_window_naming_it():
    v, t, uv = _plane(4)
    ms = MeshStrain(v, t, uv)
    assert ms.raster(32, None).shape == (32, 32) and ms.raster((32, 48), (4, 8, 10, 20)).shape == (10, 20)
    bad = [
        ((32, 32), (20, 20, 20, 20), "window must lie inside the 32 x 32 map"),  # was rasterised past the map...
        ((32, 32), (0, 0, 0, 5), r"window height must be an integer in \[1, inf\], got 0"),
        ((32, 32), (-1, 0, 5, 5), r"window row0 must be an integer in \[0, 31\], got -1"),
        ((32, 32), 5, r"window must be \(row0, col0, height, width\), got 5"),  # ...or a bare TypeError
        ((32,), (0, 0, 5, 5), r"map_shape must be an int or \(height, width\), got \(32,\)"),
        ((32.0, 32), (0, 0, 5, 5), "map_shape height must be an integer, got 32.0"),
    ]
    for map_shape, window, match in bad:
        with pytest.raises(FacestatsError, match=match):
            ms.raster(map_shape, window)


def test_rasters_are_cached_as_runs_within_a_byte_budget(monkeypatch):
    """Every tile's raster was kept as int32 for ever: about 1.6 GiB over a tiled 16K map. They are now kept as runs,
    the least recently used dropped beyond RASTER_CACHE_BYTES, and a raster given out is the caller's own."""
    from facestats.model import strain

    v, t, uv = _plane(10)
    ms = MeshStrain(v, t, uv)
    tiles = [(r, c, 32, 32) for r in (0, 32) for c in (0, 32)]
    fresh = [MeshStrain(v, t, uv).raster((64, 64), w) for w in tiles]  # each from its own, empty cache
    for window, want in zip(tiles, fresh):
        np.testing.assert_array_equal(ms.raster((64, 64), window), want)
    assert len(ms._rasters) == 4 and ms._raster_bytes < 0.5 * sum(r.nbytes for r in fresh)  # runs, not texels
    got = ms.raster((64, 64), tiles[0])
    got[:] = -7  # the caller's array, not the cache
    np.testing.assert_array_equal(ms.raster((64, 64), tiles[0]), fresh[0])  # served from the cache
    one = ms._raster_bytes // 4
    monkeypatch.setattr(strain, "RASTER_CACHE_BYTES", 2 * one + one // 2)  # room for two of the four tiles
    ms.raster((64, 64), tiles[3])  # tiles 1 and 2 are the least recently used: dropped
    assert list(ms._rasters) == [((64, 64), tiles[0]), ((64, 64), tiles[3])]
    assert ms._raster_bytes <= strain.RASTER_CACHE_BYTES
    np.testing.assert_array_equal(ms.raster((64, 64), tiles[1]), fresh[1])  # rasterised again when asked for
    monkeypatch.setattr(strain, "RASTER_CACHE_BYTES", 0)
    np.testing.assert_array_equal(ms.raster((64, 64), tiles[2]), fresh[2])  # nothing kept, still right
    assert ms._rasters == {} and ms._raster_bytes == 0


def test_overlapping_uv_charts_are_refused_and_shared_edges_are_not():
    """A whole ICT-FaceKit head (its eyes and mouth share the face's UV square) gave 96 % of the face texels the
    eyes' strain, silently (a red team): overlapping UVs are now refused; a clean mesh's shared edges pass. Here
    a second sheet 10 mm above the first, on the same UVs, overlaps it everywhere. The test is the mesh's, not
    the window's: a small overlap that would exceed the limit inside one tile (a review) passes everywhere."""
    v, t, uv = _plane(12)
    one = MeshStrain(v, t, uv)
    one.check_uv_overlap()  # its shared edges are not overlaps
    assert one.texels_strain(v, (256, 256)).valid.any()
    two = MeshStrain(np.vstack([v, v + [0, 0, 10.0]]), np.vstack([t, t + len(v)]), np.vstack([uv, uv]))
    with pytest.raises(FacestatsError, match=r"UV triangles overlap: .* inside 2\.00 triangles each .*\(1\.01 allowed"):
        two.check_uv_overlap()
    with pytest.raises(FacestatsError, match="UV triangles overlap"):
        two.texels_strain(np.vstack([v, v + [0, 0, 10.0]]), (256, 256))
    assert two.raster((64, 64), (0, 0, 64, 64)).max() >= len(t)  # rasterising alone still works: the last wins
    # a flap of one small triangle pair over the sheet: under 1 % of the layout, whatever window is rendered
    flap_v = np.array([[20.0, 20, 5], [22, 20, 5], [22, 22, 5], [20, 22, 5]])
    flap_uv = flap_v[:, :2] / 100 + [0.2, 0.3]
    flap = MeshStrain(np.vstack([v, flap_v]), np.vstack([t, [[0, 1, 2], [0, 2, 3]] + np.array(len(v))]),
                      np.vstack([uv, flap_uv]))  # fmt: skip
    deformed = np.vstack([v, flap_v])
    for window in ((0, 0, 256, 256), (125, 100, 12, 12)):  # the whole map; a window inside the flap alone
        assert flap.texels_strain(deformed, (256, 256), window=window).valid.any()


def test_bad_meshes_raise_naming_the_field():
    v, tri, uv = _plane(4)
    with pytest.raises(FacestatsError, match="deformed_vertices must have the rest mesh's 16 vertices"):
        triangle_strain(v, v[:-1], tri, uv)
    with pytest.raises(FacestatsError, match="uv must hold texture coordinates"):
        triangle_strain(v, v, tri, None)
    bad = v.copy()
    bad[3, 1] = np.nan
    with pytest.raises(FacestatsError, match="deformed_vertices must be finite"):
        triangle_strain(v, bad, tri, uv)
    with pytest.raises(FacestatsError, match="rest_vertices must be finite"):
        triangle_strain(bad, v, tri, uv)
    with pytest.raises(FacestatsError, match="triangles must index the 16 vertices"):
        triangle_strain(v, v, tri + 10, uv)
    with pytest.raises(FacestatsError, match="window must lie inside"):
        texel_strain(v, v, tri, uv, 32, window=(20, 20, 20, 20))


def test_ict_facekit_has_no_sliver_and_a_near_needle_is_one():
    """SLIVER_RATIO leaves a real face alone (ICT-FaceKit's face area: its largest UV per mm is 45.8 x the median) and
    masks a triangle squeezed to 1e-3 of its height in 3-D under an unchanged UV triangle (1000 x)."""
    from facestats.io.ict_facekit import read_ict_facekit
    from facestats.model.strain import SLIVER_RATIO, slivers, uv_metric
    from tests.helpers import TEST_DATA

    mesh, _ = read_ict_facekit(TEST_DATA / "ict-facekit", [])
    ms = MeshStrain(mesh.vertices, mesh.triangles, mesh.uv, mesh.uv_triangles)
    assert not ms.rest_slivers.any()
    corners = mesh.uv[mesh.uv_triangles]
    m, degenerate = uv_metric(mesh.vertices, mesh.triangles, corners)
    top = np.linalg.eigvalsh(m[~degenerate])[:, 1]
    assert np.max(top) / np.median(top) == pytest.approx(45.8, abs=0.05) and 45.8 < SLIVER_RATIO / 2
    # The same mesh with one vertex pulled onto the line through two neighbours: its triangles there become slivers.
    f = int(np.argsort(top)[len(top) // 2])  # an ordinary triangle
    a, b, c = mesh.triangles[~degenerate][f]
    squeezed = mesh.vertices.copy()
    foot = squeezed[a] + np.dot(squeezed[c] - squeezed[a], squeezed[b] - squeezed[a]) / np.sum(
        (squeezed[b] - squeezed[a]) ** 2
    ) * (squeezed[b] - squeezed[a])
    squeezed[c] = foot + 1e-3 * (squeezed[c] - foot)
    m2, deg2 = uv_metric(squeezed, mesh.triangles, corners)
    hit = slivers(m2, deg2)
    assert hit[np.flatnonzero(~degenerate)[f]] and not hit[~np.any(mesh.triangles == c, axis=1)].any()


def test_anisotropic_uv_on_a_non_square_map_gives_each_axis_its_own_texel_size():
    """uv = (x / 100, y / 40) on 64 rows x 128 columns: a mm is W/100 = 1.28 texels along x, H/40 = 1.6 along y.
    A stretch of 1.2 at 30 deg and 0.9 across (in the sheet's plane): r_s, r_t are those (T = M'⁻¹ M, eq. 10;
    M M'⁻¹ has other singular values where M is not a multiple of I), the s axis in texels is along (1.28 cos 30,
    1.6 sin 30) with 1000 / |that| um per texel, the t axis along (−1.28 sin 30, 1.6 cos 30), and the UV per um
    of each axis is the UV length of a um along it (eq. 13's column norms)."""
    n = 8
    x, y = np.meshgrid(np.linspace(0, 50.0, n), np.linspace(0, 40.0, n))
    v = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], 1)
    uv = np.stack([x.ravel() / 100 + 0.2, y.ravel() / 40 + 0.02], 1)
    tri = grid_triangles(np.ones((n, n), bool))
    deformed = (v @ _stretch(30, 1.2, 0.9).T) @ ROT3.T
    st = texel_strain(v, deformed, tri, uv, (64, 128))
    ok = st.valid
    assert ok.sum() > 1000
    assert np.abs(st.r_s[ok] - 1.2).max() < 1e-12 and np.abs(st.r_t[ok] - 0.9).max() < 1e-12
    c, s = np.cos(np.radians(30)), np.sin(np.radians(30))
    for axis, texel, uv_um, along, world in (
        (st.axis_s, st.texel_um_s, st.uv_per_um_s, np.array([1.28 * c, 1.6 * s]), np.array([c, s])),
        (st.axis_t, st.texel_um_t, st.uv_per_um_t, np.array([-1.28 * s, 1.6 * c]), np.array([-s, c])),
    ):
        unit = along / np.linalg.norm(along)
        assert np.abs(np.abs(axis[ok] @ unit) - 1).max() < 1e-9  # parallel (either sign)
        assert np.abs(texel[ok] - 1000 / np.linalg.norm(along)).max() < 1e-6
        assert np.abs(uv_um[ok] - np.linalg.norm(world / [100, 40]) / 1000).max() < 1e-15


def test_texel_strain_interpolates_the_uv_vertex_averages_of_t_at_texel_centres():
    """A bent sheet (not a uniform strain): each UV vertex takes the mean T of its triangles (checked against
    triangle_strain), and a texel the barycentric interpolation of its triangle's three vertex tensors at its centre
    ((column + 0.5) / W, (row + 0.5) / H in UV), computed here by solving for the barycentric coordinates."""
    n = 7
    x, y = np.meshgrid(np.linspace(0, 30.0, n), np.linspace(0, 24.0, n))
    v = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], 1)
    uv = np.stack([x.ravel() / 40 + 0.1, y.ravel() / 30 + 0.1], 1)
    tri = grid_triangles(np.ones((n, n), bool))
    deformed = v + np.stack([0.004 * v[:, 0] ** 2, 0.01 * v[:, 0] * v[:, 1], 0.002 * v[:, 1] ** 2], 1)
    per_tri = triangle_strain(v, deformed, tri, uv)
    vert = vertex_strain(v, deformed, tri, uv)
    for k in range(len(uv)):
        around = np.nonzero((tri == k).any(1))[0]
        assert np.abs(vert.t[k] - per_tri.t[around].mean(0)).max() < 1e-12
    shape = (24, 40)
    mesh = MeshStrain(v, tri, uv)
    st = mesh.texels_strain(deformed, shape)
    owner = mesh.raster(shape, (0, 0) + shape)
    rows, cols = np.nonzero(st.valid)
    assert rows.size > 300
    p = np.stack([(cols + 0.5) / shape[1], (rows + 0.5) / shape[0]], 1)
    corners = uv[tri[owner[rows, cols]]]  # (K, 3, 2)
    lam12 = np.linalg.solve(np.stack([corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]], -1),
                            (p - corners[:, 0])[..., None])[..., 0]  # fmt: skip
    bary = np.concatenate([1 - lam12.sum(1, keepdims=True), lam12], 1)
    expected = np.einsum("kc,kcij->kij", bary, vert.t[tri[owner[rows, cols]]])
    assert np.abs(st.t[rows, cols] - expected).max() < 1e-12


def test_invalid_entries_read_the_identity_and_thin_is_a_sine_below_1e_9():
    """Entries not valid carry T = I (r = 1, docstring of Strain) whatever their triangles did; a triangle is
    degenerate when |e1 × e2| ≤ 1e-9 |e1| |e2|: a sine of 2e-6 is thin but valid.  A triangle collapsed onto a line
    in general position (sine ~1e-16 from rounding) is degenerate: the sine was taken from the Gram determinant
    |e1|²|e2|² − (e1·e2)², whose cancellation leaves ~1e-16 |e1|²|e2|² (a sine of ~1e-8), and 74 of 200 such
    triangles passed as valid with r_t ~ 1e-8 (a mutation audit)."""
    v, tri, uv = _plane(6)
    rng = np.random.default_rng(0)
    for _ in range(50):
        deformed = v * [1.3, 1.0, 1.0]
        deformed[tri[3]] = rng.uniform(-50, 50, 3) + rng.uniform(0, 1, (3, 1)) * rng.uniform(-50, 50, 3)
        st = triangle_strain(v, deformed, tri, uv)
        assert np.nonzero(~st.valid)[0].tolist() == [3] and st.n_degenerate == 1
    assert np.array_equal(st.t[~st.valid], np.broadcast_to(np.eye(2), (int((~st.valid).sum()), 2, 2)))
    assert np.all(st.r_s[~st.valid] == 1) and np.all(st.r_t[~st.valid] == 1)
    thin = np.array([[0.0, 0, 0], [1.0, 0, 0], [0.5, 1e-6, 0]])  # sine 2e-6 in 3-D
    st = triangle_strain(thin, thin * [1.1, 1, 1], np.array([[0, 1, 2]]), np.array([[0, 0], [1, 0], [0, 1.0]]) / 10)
    assert st.valid.all() and st.r_s[0] > 1.0


def test_slivers_compare_with_the_median_of_the_valid_triangles_only():
    """A sliver's largest eigenvalue of M exceeds SLIVER_RATIO (100) × the median over the *other valid*
    triangles: many degenerate ones (their M is set to I) must not move that median."""
    from facestats.model.strain import slivers

    top = np.array([1.0, 1.0, 1.0, 150.0] + [1000.0] * 5)
    m = top[:, None, None] * np.eye(2)
    degenerate = np.array([False] * 4 + [True] * 5)
    assert slivers(m, degenerate).tolist() == [False, False, False, True] + [False] * 5
