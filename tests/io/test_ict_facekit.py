"""The ICT-FaceKit face (MIT licence; sample in tests/data/ict-facekit): strain where a person expects it.

Landmark vertices from ICT-FaceKit's README (Multi-PIE 68 points): 0 = upper lip (51),
5518 = lower lip (57), 5708 / 6213 = mouth corners (48 / 54); the forehead is the face
area above y = 70 mm.
"""

import numpy as np
import pytest

from facestats.io.ict_facekit import FACE_VERTICES, read_ict_facekit
from facestats.model.strain import MeshStrain
from tests.helpers import TEST_DATA

DATA = TEST_DATA / "ict-facekit"
UPPER_LIP, LOWER_LIP, CORNERS = 0, 5518, (5708, 6213)


@pytest.fixture(scope="module")
def ict():
    neutral, targets = read_ict_facekit(DATA)
    ms = MeshStrain(neutral.vertices, neutral.triangles, neutral.uv, neutral.uv_triangles)
    uv_of = np.full(neutral.n_vertices, -1)
    uv_of[ms.triangles.ravel()] = ms.uv_triangles.ravel()  # a UV vertex of each 3-D vertex
    return neutral, targets, ms, uv_of


def _combine(neutral, targets, *names):
    return neutral.vertices + sum(targets[n] - neutral.vertices for n in names)


def _angle(a):
    return np.degrees(np.arctan2(a[..., 1], a[..., 0])) % 180


def test_sample_reads_as_the_face_area(ict):
    neutral, targets, ms, _ = ict
    assert neutral.n_vertices == FACE_VERTICES and len(neutral.triangles) == 2 * 9230
    assert sorted(targets) == ["browInnerUp_L", "browInnerUp_R", "jawOpen", "mouthSmile_L", "mouthSmile_R"]
    extent = neutral.vertices.max(0) - neutral.vertices.min(0)
    assert 150 < extent[0] < 200 and 0 <= neutral.uv.min() and neutral.uv.max() <= 1  # mm, v down
    assert ms.islands().max() >= 1 and not ms.rest_degenerate.any()


def test_smile_stretches_the_lips_sideways_and_bunches_the_cheeks(ict):
    neutral, targets, ms, uv_of = ict
    st = ms.vertices_strain(_combine(neutral, targets, "mouthSmile_L", "mouthSmile_R"))
    for v in (UPPER_LIP, LOWER_LIP):  # lips pulled sideways: stretch along u
        assert st.r_s[uv_of[v]] > 1.3 and min(_angle(st.axis_s[uv_of[v]]), 180 - _angle(st.axis_s[uv_of[v]])) < 15
    for v in CORNERS:  # the cheek bunches at the mouth corners: compression across, along u
        assert st.r_t[uv_of[v]] < 0.9 and abs(_angle(st.axis_t[uv_of[v]]) - 90) > 45
    forehead = np.unique(uv_of[neutral.vertices[:, 1] > 70])
    assert np.abs(st.r_s[forehead] - 1).max() < 0.01 and np.abs(st.r_t[forehead] - 1).max() < 0.01


def test_open_jaw_stretches_the_mouth_corners_vertically(ict):
    neutral, targets, ms, uv_of = ict
    st = ms.vertices_strain(targets["jawOpen"])
    for v in CORNERS:
        assert st.r_s[uv_of[v]] > 2 and abs(_angle(st.axis_s[uv_of[v]]) - 90) < 10
    forehead = np.unique(uv_of[neutral.vertices[:, 1] > 70])
    assert np.abs(st.r_s[forehead] - 1).max() < 0.01


def test_raised_brows_compress_the_forehead(ict):
    neutral, targets, ms, uv_of = ict
    st = ms.vertices_strain(_combine(neutral, targets, "browInnerUp_L", "browInnerUp_R"))
    forehead = np.unique(uv_of[neutral.vertices[:, 1] > 70])
    assert np.percentile(st.r_t[forehead], 1) < 0.8  # furrows form
    chin = np.unique(uv_of[neutral.vertices[:, 1] < -60])
    assert np.abs(st.r_s[chin] - 1).max() < 0.01


def test_texel_strain_agrees_with_the_vertices_and_plots(ict):
    import matplotlib

    matplotlib.use("Agg")
    from facestats.model.microstructure.plots import plot_strain

    neutral, targets, ms, uv_of = ict
    deformed = _combine(neutral, targets, "mouthSmile_L", "mouthSmile_R")
    ts = ms.texels_strain(deformed, 256)
    vs = ms.vertices_strain(deformed)
    u = uv_of[UPPER_LIP]
    row, col = (neutral.uv[u, ::-1] * 256).astype(int)
    assert abs(ts.r_s[row, col] / vs.r_s[u] - 1) < 0.05
    assert ts.valid.mean() > 0.8 and np.all(np.isfinite(ts.r_s)) and ts.n_degenerate == 0
    fig = plot_strain(ts)
    assert len(fig.axes) == 6
