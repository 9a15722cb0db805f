"""The compiled depth buffer of the shadow maps equals the numpy one bit for bit, on real and hostile meshes."""

import numpy as np
import pytest

from facestats.acquire.dome import default_dome
from facestats.acquire.visibility import shadow_map
from facestats.face.named import face_geometry

pytest.importorskip("numba")


def _both(verts, faces, eye, target, radius, res):
    a, cam_a = shadow_map(verts, faces, eye, target, radius, res, backend="numba")
    b, cam_b = shadow_map(verts, faces, eye, target, radius, res, backend="numpy")
    assert cam_a[2] == cam_b[2] and np.array_equal(cam_a[1], cam_b[1])
    return a, b


@pytest.mark.parametrize("face", ["ict", "procedural"])
def test_face_meshes_from_dome_leds_and_cameras(face):
    g = face_geometry(face, 8)
    dome = default_dome()
    verts = np.asarray(g.mesh_vertices, float)
    target = 0.5 * (verts.min(0) + verts.max(0))
    radius = 1.05 * np.max(np.linalg.norm(verts - target, axis=1))
    eyes = np.concatenate([dome.led_position[::15], dome.camera_position[::4]])
    for eye in eyes:
        a, b = _both(verts, g.mesh_faces, eye, target, radius, 96)
        assert np.array_equal(a, b)  # inf where empty in both, identical depths elsewhere
        assert np.isfinite(a).mean() > 0.05  # the face is in view: the test compares depths, not empty buffers


def test_random_soup_with_degenerate_offscreen_and_behind_camera_triangles():
    rng = np.random.default_rng(7)
    verts = rng.normal(0, 40, (300, 3))
    verts[:10, 2] = 900  # behind the eye at z = 600 looking at the origin
    verts[10:20] = verts[20:30]  # duplicated vertices: zero-area triangles below
    faces = rng.integers(0, 300, (900, 3))
    faces[:20] = np.stack([np.arange(10, 30), np.arange(20, 40), np.arange(10, 30)], 1)  # degenerate
    verts[40] = [np.nan, 0, 0]
    for res in (17, 64, 200):
        a, b = _both(verts, faces, [0.0, 0.0, 600.0], [0.0, 0.0, 0.0], 160.0, res)
        assert np.array_equal(a, b)
        assert np.isfinite(a).any() and np.isinf(a).any()


def test_a_vertex_just_in_front_of_the_eye_costs_no_more_than_the_grid():
    """Its projection lies ~1e11 pixels away: the candidate box is clipped to the grid before any integer
    conversion (the numpy path would allocate that box), and the triangle still occludes what it covers."""
    eye = np.array([0.0, 0.0, 600.0])
    verts = np.array([[1.0, 0.5, 600.0 - 1e-9], [-50.0, -50.0, 0.0], [50.0, -50.0, 0.0], [0.0, 60.0, 0.0]])
    faces = np.array([[0, 1, 2], [1, 2, 3]])
    depth, _ = shadow_map(verts, faces, eye, [0.0, 0.0, 0.0], 160.0, 64, backend="numba")
    only_far, _ = shadow_map(verts, faces[1:], eye, [0.0, 0.0, 0.0], 160.0, 64, backend="numba")
    assert np.isfinite(only_far).any()
    near = depth < only_far  # pixels the sliver in front of the eye covers
    assert near.any() and np.all(depth <= only_far)
    # a wedge from a vertical edge to a vertex projected beyond 2^63 pixels: still drawn (math.floor's int64
    # dropped it; a red team); 1e3 mm gives ~1e18 pixels, which both versions drew
    for far in (1e3, 1e4):
        verts = np.array([[far, 0.0, np.nextafter(600.0, 0)], [-50, -50, 0], [-50, 50, 0], [50, 0, -10]])
        wedge, _ = shadow_map(verts, np.array([[0, 1, 2], [1, 2, 3]]), eye, [0.0, 0.0, 0.0], 160.0, 64)
        behind, _ = shadow_map(verts, np.array([[1, 2, 3]]), eye, [0.0, 0.0, 0.0], 160.0, 64)
        assert np.sum(wedge < behind) > 500, far


def test_faces_outside_the_vertices_or_not_triangles_are_refused_by_both_paths():
    """Two-column faces made the compiled path read past the array (a segmentation fault; a red team), float
    faces were truncated to indices: both paths refuse them by name."""
    from facestats.errors import ValidationError

    verts = np.random.default_rng(0).normal(0, 40, (50, 3))
    args = ([0.0, 0.0, 600.0], [0.0, 0.0, 0.0], 160.0, 32)
    for backend in ("numba", "numpy"):
        with pytest.raises(IndexError):
            shadow_map(verts, np.array([[0, 1, 50]]), *args, backend=backend)
        for bad in (np.array([[0, 1]] * 60), np.array([[0.0, 1.3, 2.0]]), np.array([0, 1, 2])):
            with pytest.raises(ValidationError, match=r"faces must be an \(F, 3\) array of integer vertex indices"):
                shadow_map(verts, bad, *args, backend=backend)
