"""facestats.io.mesh.write_mesh: a plain triangle mesh (no UVs) and one with UVs, read back as written."""

import numpy as np
import pytest

from facestats.acquire.patches import mesh_patches, read_mesh_patches
from facestats.errors import FormatError, ValidationError
from facestats.io.mesh import load_face_mesh, read_triangle_mesh, write_mesh


def _mesh(seed=0):
    """A random mesh in mm whose every vertex some triangle uses, corners in no particular order."""
    rng = np.random.default_rng(seed)
    vertices = rng.uniform(-40, 40, (12, 3))
    faces = np.array([[0, 1, 2], [2, 1, 3], [4, 5, 6], [6, 5, 7], [8, 9, 10], [11, 10, 9], [3, 0, 11]])
    return vertices, faces


@pytest.mark.parametrize("ext", [".obj", ".ply"])
def test_a_mesh_without_uvs_is_read_back_by_the_translucency_reader_as_written(tmp_path, ext):
    """uv=None writes vertices and triangles only; read_triangle_mesh (facestats translucency's reader, through
    read_mesh_patches) gets the same vertices (OBJ: 8 decimals; PLY: float32), the same faces in the same corner
    order, no UVs, and so the same patches as the arrays (as stored) give."""
    vertices, faces = _mesh()
    path = write_mesh(tmp_path / f"plain{ext}", vertices, faces)
    assert path == str(tmp_path / f"plain{ext}")
    back, back_faces, uv = read_triangle_mesh(path, uv=True)
    assert uv is None
    np.testing.assert_array_equal(back_faces, faces)
    if ext == ".obj":
        np.testing.assert_allclose(back, vertices, rtol=0, atol=5e-9)
        lines = (tmp_path / "plain.obj").read_text().splitlines()
        assert not [ln for ln in lines if ln.startswith(("vt ", "vn ", "mtllib ", "usemtl "))]
        assert [ln for ln in lines if ln.startswith("f ")][:2] == ["f 1 2 3", "f 3 2 4"]  # 1-based, corners in order
    else:
        np.testing.assert_array_equal(back, vertices.astype(np.float32))
    stored = vertices if ext == ".obj" else vertices.astype(np.float32).astype(np.float64)
    ours, theirs = mesh_patches(stored, faces, spacing=3.0), read_mesh_patches(path, spacing=3.0)
    assert len(theirs) == len(ours) > len(faces)
    for name in ("centre", "normal", "area"):
        np.testing.assert_allclose(getattr(theirs, name), getattr(ours, name), rtol=1e-6, atol=1e-6)
    # without UVs it is no face scan: load_face_mesh says what is missing
    with pytest.raises(FormatError, match="has no per-vertex UV coordinates"):
        load_face_mesh(path, np.ones((4, 4), np.uint8))


def test_an_obj_read_back_loses_only_the_vertices_no_triangle_uses(tmp_path):
    """The writer writes every vertex; trimesh's reader drops the unused ones and renumbers: the triangles stay."""
    vertices, faces = _mesh()
    kept = faces[[0, 2, 4]]  # vertices 3, 7 and 11 unused
    write_mesh(tmp_path / "sparse.obj", vertices, kept)
    assert sum(ln.startswith("v ") for ln in (tmp_path / "sparse.obj").read_text().splitlines()) == len(vertices)
    back, back_faces = read_triangle_mesh(tmp_path / "sparse.obj")
    assert len(back) == len(vertices) - 3
    np.testing.assert_allclose(back[back_faces], vertices[kept], rtol=0, atol=5e-9)


@pytest.mark.parametrize("ext", [".obj", ".ply"])
def test_a_mesh_with_uvs_still_round_trips(tmp_path, ext):
    """With uv the file stores (u, 1 − v) per vertex (v up), read back with the same vertices and faces."""
    vertices, faces = _mesh(1)
    uv = np.random.default_rng(2).uniform(0, 1, (len(vertices), 2))
    normals = np.cross(vertices, [0.0, 0.0, 1.0]) + [0.0, 0.0, 1.0]
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    write_mesh(tmp_path / f"uv{ext}", vertices, faces, uv, normals)
    back, back_faces, stored = read_triangle_mesh(tmp_path / f"uv{ext}", uv=True)
    np.testing.assert_array_equal(back_faces, faces)
    tol = 5e-9 if ext == ".obj" else 4e-6  # OBJ 8 decimals, PLY float32
    np.testing.assert_allclose(back, vertices, rtol=0, atol=tol)
    np.testing.assert_allclose(stored, np.stack([uv[:, 0], 1 - uv[:, 1]], 1), rtol=0, atol=tol)
    if ext == ".obj":
        text = (tmp_path / "uv.obj").read_text()
        assert "vt " in text and "vn " in text and "mtllib" not in text


def test_bad_arrays_are_refused_before_anything_is_written(tmp_path):
    vertices, faces = _mesh()
    with pytest.raises(ValidationError, match=r"uv"):
        write_mesh(tmp_path / "a.obj", vertices, faces, np.zeros((3, 2)))
    with pytest.raises(ValidationError, match=r"faces must index 0\.\.11, got 0\.\.12"):
        write_mesh(tmp_path / "a.obj", vertices, np.vstack([faces, [[0, 1, 12]]]))
    with pytest.raises(ValidationError, match=r"faces must be integer vertex indices, got dtype float64"):
        write_mesh(tmp_path / "a.obj", vertices, faces + 0.5)
    with pytest.raises(ValidationError, match=r"must end in \.obj or \.ply, got '.*a\.stl'"):
        write_mesh(tmp_path / "a.stl", vertices, faces)
    assert list(tmp_path.iterdir()) == []
