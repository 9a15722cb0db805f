"""Mesh sequences: OBJ with per-corner UVs, PLY, frame files, blendshapes with weights; bad input."""

import numpy as np
import pytest

from facestats.errors import FacestatsError
from facestats.io.ict_facekit import read_ict_facekit
from facestats.io.mesh_sequence import BlendshapeSequence, FrameSequence, read_mesh, read_obj, read_weights
from tests.helpers import TEST_DATA

DATA = TEST_DATA / "ict-facekit"

QUAD_OBJ = """# two quads sharing an edge, with a UV seam on the shared edge
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 2 0 0
v 2 1 0
vt 0.0 0.0
vt 0.4 0.0
vt 0.4 0.5
vt 0.0 0.5
vt 0.6 0.0
vt 1.0 0.0
vt 1.0 0.5
vt 0.6 0.5
f 1/1 2/2 3/3 4/4
f 2/5 5/6 6/7 3/8
"""


def _write(path, text):
    path.write_text(text)
    return path


def test_obj_keeps_per_corner_uvs_and_splits_quads(tmp_path):
    m = read_obj(_write(tmp_path / "q.obj", QUAD_OBJ), scale=10)
    assert m.vertices.shape == (6, 3) and m.vertices[4, 0] == 20  # scaled to mm
    assert m.triangles.tolist() == [[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2]]
    assert m.uv_triangles.tolist() == [[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]]  # the seam is kept
    assert m.polygon.tolist() == [0, 0, 1, 1]
    assert np.allclose(m.uv[2], [0.4, 0.5])  # v flipped: 1 - 0.5


def test_frames_and_topology_checks(tmp_path):
    neutral = read_obj(_write(tmp_path / "n.obj", QUAD_OBJ))
    moved = QUAD_OBJ.replace("v 2 1 0", "v 2.5 1 0")
    seq = FrameSequence(neutral, [_write(tmp_path / "f0.obj", QUAD_OBJ), _write(tmp_path / "f1.obj", moved)])
    assert len(seq) == 2 and seq.frame(1)[5].tolist() == [2.5, 1, 0]
    bad = FrameSequence(
        neutral, [_write(tmp_path / "b.obj", QUAD_OBJ.replace("f 2/5 5/6 6/7 3/8", "f 2/5 6/6 5/7 3/8"))]
    )
    with pytest.raises(FacestatsError, match="topology differs.*faces differ"):
        bad.frame(0)
    short = FrameSequence(neutral, [_write(tmp_path / "s.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\n")])
    with pytest.raises(FacestatsError, match="topology differs.*3 vertices, expected 6"):
        short.frame(0)
    nan = FrameSequence(neutral, [_write(tmp_path / "nan.obj", QUAD_OBJ.replace("v 1 1 0", "v nan 1 0"))])
    with pytest.raises(FacestatsError, match="must be finite"):
        nan.frame(0)
    no_uv = read_obj(_write(tmp_path / "nouv.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 3\n"))
    with pytest.raises(FacestatsError, match="no texture coordinates"):
        FrameSequence(no_uv, [tmp_path / "nouv.obj"])
    with pytest.raises(FacestatsError, match="existing frame files"):
        FrameSequence(neutral, [tmp_path / "missing.obj"])


def test_ply_reads_per_vertex_uvs(tmp_path):
    import trimesh

    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    mesh = trimesh.Trimesh(v, [[0, 1, 2], [0, 2, 3]], process=False)
    mesh.visual = trimesh.visual.TextureVisuals(uv=np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float))
    mesh.export(tmp_path / "m.ply")
    m = read_mesh(tmp_path / "m.ply")
    assert m.triangles.tolist() == [[0, 1, 2], [0, 2, 3]] and np.allclose(m.uv[2], [1, 0])  # v flipped


def test_blendshapes_and_weights(tmp_path):
    neutral, targets = read_ict_facekit(DATA, ["mouthSmile_L", "jawOpen"])
    (tmp_path / "w.csv").write_text("frame,jawOpen,mouthSmile_L\n0,0,0\n1,0.5,1\n")
    names, w = read_weights(tmp_path / "w.csv")
    assert names == ["jawOpen", "mouthSmile_L"] and w.tolist() == [[0, 0], [0.5, 1]]
    seq = BlendshapeSequence(neutral, targets, w, names=names)
    expect = 0.5 * targets["jawOpen"] + targets["mouthSmile_L"] - 0.5 * neutral.vertices
    assert np.abs(seq.frame(1) - expect).max() < 1e-12 and np.array_equal(seq.frame(0), neutral.vertices)
    with pytest.raises(FacestatsError, match="weights must have shape"):
        BlendshapeSequence(neutral, targets, np.ones((3, 3)), names=names)
    with pytest.raises(FacestatsError, match="topology differs"):
        BlendshapeSequence(neutral, {"x": neutral.vertices[:-1]}, np.ones((1, 1)))
    (tmp_path / "bad.csv").write_text("jawOpen\n0.5\n\n,\n")
    with pytest.raises(FacestatsError, match="weights"):
        read_weights(tmp_path / "bad.csv")
    with pytest.raises(FacestatsError, match="ICT-FaceKit checkout"):
        read_ict_facekit(tmp_path)


@pytest.mark.parametrize(
    "transform, match",
    [
        (np.diag([1.0, 1.0, -1.0, 1.0]), "got a mirror .det = -1.: it turns the mesh inside out"),
        (np.diag([2.0, 2.0, 2.0, 1.0]), r"must be rigid .* singular values \[2.0, 2.0, 2.0\]: pass a scale as scale="),
        (np.vstack([np.eye(4)[:3], [0.0, 0.0, 0.0, 1000.0]]), r"bottom row \[0, 0, 0, 1\]"),
        (np.eye(3), r"4x4 matrix, got shape \(3, 3\)"),
    ],
)
def test_a_transform_must_be_rigid_in_both_mesh_readers(tmp_path, transform, match):
    """A mirror turned the normals into the head, a scale quadrupled the areas and a bottom row of 1000 was
    ignored, all silently (an API red team); the scan reader and the sequence reader share the check."""
    from facestats.io.mesh import read_triangle_mesh

    path = _write(tmp_path / "q.obj", QUAD_OBJ)
    for read in (lambda: read_obj(path, transform=transform), lambda: read_triangle_mesh(path, transform=transform)):
        with pytest.raises(FacestatsError, match=match):
            read()
    turn = np.eye(4)
    turn[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]  # 90 degrees about z, then moved
    turn[:3, 3] = [5.0, 0.0, 0.0]
    assert np.allclose(read_obj(path, transform=turn).vertices[1], [5.0, 1.0, 0.0])


def test_an_obj_with_textured_materials_keeps_its_own_uvs(tmp_path):
    """With an .mtl naming a texture per part beside it, trimesh packed the parts' textures into one atlas and
    rewrote the UVs (0.1..0.9 became 0.16..0.83 across): export --mesh put the maps on the wrong vertices (a
    user's run on ICT-FaceKit's full mesh)."""
    from PIL import Image

    from facestats.io.mesh import read_triangle_mesh

    for name, grey in (("a", 100), ("b", 200)):
        Image.fromarray(np.full((4, 4, 3), grey, np.uint8)).save(tmp_path / f"{name}.png")
    (tmp_path / "m.mtl").write_text("newmtl A\nmap_Kd a.png\nnewmtl B\nmap_Kd b.png\n")
    (tmp_path / "m.obj").write_text(
        "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0.1 0.1\nvt 0.9 0.1\nvt 0.1 0.9\nvt 0.9 0.9\n"
        "usemtl A\nf 1/1 2/2 3/3\nusemtl B\nf 2/2 4/4 3/3\n"
    )
    verts, faces, uv = read_triangle_mesh(tmp_path / "m.obj", uv=True)
    corners = {tuple(np.round(verts[i], 6)): tuple(np.round(uv[i], 6)) for i in faces.ravel()}
    assert corners == {(0, 0, 0): (0.1, 0.1), (1, 0, 0): (0.9, 0.1), (0, 1, 0): (0.1, 0.9), (1, 1, 0): (0.9, 0.9)}


def test_a_missing_mesh_is_named_as_missing(tmp_path):
    """'/nope' was refused as "must be .obj or .ply" (a fresh-user red team); a wrong suffix still says so."""
    with pytest.raises(FacestatsError, match="must name an existing .obj or .ply file, got '.*nope.obj'"):
        read_mesh(tmp_path / "nope.obj")
    (tmp_path / "mesh.stl").write_text("solid x\nendsolid x\n")
    with pytest.raises(FacestatsError, match=r"must be .obj or .ply, got '.*mesh.stl'"):
        read_mesh(tmp_path / "mesh.stl")
