"""Procedural skin microstructure (seeded, per region from a store subject)."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.ndimage import binary_erosion
from scipy.stats import skew

import facestats
from facestats.acquire.synthetic.microstructure import (
    SkinMicrostructure,
    procedural_microstructure,
    shot_noise_microstructure,
    subject_microstructure,
    subject_microstructure_parameters,
)
from facestats.errors import FacestatsError
from facestats.model.microstructure.fit import deformation_matrix
from facestats.model.microstructure.surface import slopes


def _rms_slope(h, texel, mask=None):
    gx, gy = slopes(h, np.eye(2) / texel)
    sel = np.ones(h.shape, bool) if mask is None else mask
    return float(np.sqrt(np.mean(gx[sel] ** 2 + gy[sel] ** 2))), float(np.mean(gx[sel] ** 2) / np.mean(gy[sel] ** 2))


def test_seeded_and_scaled_to_the_roughness():
    p = SkinMicrostructure(roughness=0.3)
    a = procedural_microstructure(384, 12.0, params=p, seed=5)
    assert np.array_equal(a, procedural_microstructure(384, 12.0, params=p, seed=5))
    assert not np.array_equal(a, procedural_microstructure(384, 12.0, params=p, seed=6))
    rms, _ = _rms_slope(a, 12.0)
    assert abs(rms / 0.3 - 1) < 0.1  # closed-form scaling, measured by central differences
    assert skew(a.ravel()) < -0.3  # pits and grooves: heavy negative tail
    assert a.dtype == np.float32 and a.shape == (384, 384)


@pytest.mark.parametrize("angle, ratio", [(0.0, "below"), (np.pi / 2, "above")])
def test_furrows_follow_the_region_direction(angle, ratio):
    p = SkinMicrostructure(roughness=0.3, furrow_angle=angle, furrow_share=0.8, pore_share=0.0)
    _, r = _rms_slope(procedural_microstructure(384, 15.0, params=p, seed=1), 15.0)
    # grooves along u vary across v: slopes along v dominate (and the other way round)
    assert (r < 0.5) if ratio == "below" else (r > 2.0)


def test_deformation_renders_the_same_realisation_stretched():
    p = SkinMicrostructure(roughness=0.3, pore_share=0.0)
    h = procedural_microstructure(256, 10.0, params=p, seed=3)
    assert np.array_equal(procedural_microstructure(256, 10.0, params=p, seed=3, deformation=np.eye(2)), h)
    stretched = procedural_microstructure(256, 10.0, params=p, seed=3, deformation=deformation_matrix((1, 0), 2.0))
    # h'(x) = h(A^-1 x): column 2j of the stretched map is column j of the original (texel centres differ by
    # half a texel, so compare against the analytic shift on a smooth field)
    rms_h, _ = _rms_slope(h, 10.0)
    rms_s, r_s = _rms_slope(stretched, 10.0)
    assert rms_s < rms_h and r_s < 0.6  # slopes along the stretch halve


def test_subject_regions_get_the_subjects_roughness():
    with facestats.open_store() as store:
        ds = store.subject("S001")
    params = subject_microstructure_parameters(ds)
    region = np.asarray(ds["region"].values)
    m = np.asarray(ds["ts_m"].values)
    assert params[2].roughness == pytest.approx(np.median(m[(region == 2) & np.isfinite(m)]))
    # 1024² so that the default face's regions (ICT-FaceKit's UV layout: the forehead is 134 of 2,304
    # texels at 48²) hold cores of thousands of texels; a slope RMS over fewer is too noisy to test.
    size, texel = 1024, 15.0
    h = subject_microstructure(ds, size, texel)
    assert np.array_equal(h, subject_microstructure(ds, size, texel))  # seed from the subject id
    idx = np.minimum(((np.arange(size) + 0.5) * region.shape[0] / size).astype(int), region.shape[0] - 1)
    full = region[np.ix_(idx, idx)]
    checked = 0
    for k in (2, 7, 10):  # regions large enough to hold a core away from the blends
        core = binary_erosion(full == k, iterations=25)
        if core.sum() > 1500:
            rms, _ = _rms_slope(h, texel, core)
            assert abs(rms / params[k].roughness - 1) < 0.15, k
            checked += 1
    assert checked >= 2


def test_bad_input():
    with pytest.raises(FacestatsError, match="furrow_share \\+ pore_share must be <= 1"):
        SkinMicrostructure(furrow_share=0.8, pore_share=0.5)
    with pytest.raises(FacestatsError, match="texel_um must lie in"):
        procedural_microstructure(64, -1.0)
    with pytest.raises(FacestatsError, match="deformation must be a 2x2 matrix with a positive determinant"):
        procedural_microstructure(64, 10.0, deformation=np.diag([1.0, -1.0]))
    with pytest.raises(FacestatsError, match="region_map must be a 2-D integer label map"):
        procedural_microstructure(64, 10.0, region_map=np.zeros((4, 4), float))


def test_shot_noise_surface_has_the_stated_rms_slope_and_tiles():
    kw = dict(density_mm2=2000.0, bump_radius_um=20.0, rms_slope=0.3)
    msq = []
    for seed in range(24):  # mean square over seeds: each map holds ~9,200 bumps, its own scatters by ~2.5 %
        h = shot_noise_microstructure((128, 160), 15.0, seed=seed, **kw).astype(np.float64)
        wrapped = np.pad(h, 1, mode="wrap")  # periodic: central differences across the seam
        gu = (wrapped[1:-1, 2:] - wrapped[1:-1, :-2]) / 30.0
        gv = (wrapped[2:, 1:-1] - wrapped[:-2, 1:-1]) / 30.0
        msq.append(np.mean(gu**2 + gv**2))
    assert abs(np.mean(msq) / 0.3**2 - 1) < 0.02  # closed-form scale; the 24-seed mean scatters by ~0.5 %
    h = shot_noise_microstructure((256, 320), 15.0, seed=5, **kw)
    assert h.shape == (256, 320) and h.dtype == np.float32
    assert np.array_equal(h, shot_noise_microstructure((256, 320), 15.0, seed=5, **kw))
    assert not np.array_equal(h, shot_noise_microstructure((256, 320), 15.0, seed=6, **kw))
    with pytest.raises(FacestatsError, match="density_mm2 must lie in"):
        shot_noise_microstructure(64, density_mm2=0.0)
    with pytest.raises(FacestatsError, match="bump_radius_um must be at most"):
        shot_noise_microstructure(64, 10.0, bump_radius_um=200.0)


def _s001_region():
    with facestats.open_store() as store:
        ds = store.subject("S001")
    return ds, np.asarray(ds["region"].values).astype(np.int64)


def test_a_window_holds_the_regions_that_lie_there_on_the_subjects_face():
    """The render window of docs/microstructure.md (the cheek, rows 9046-9558 and columns 6077-6589 of the 16K
    map) generated alone holds the regions of S001's region map over that window — cheeks, lips, beard — and
    nothing of the other seven.  (Before, a map spanned its region map whatever it stood for: a 512² map at
    15 µm held all ten regions, forehead furrows and brows included, in 7.7 mm.)"""
    from scipy.ndimage import maximum_filter

    from facestats.acquire.synthetic.microstructure import region_labels

    _, region = _s001_region()
    shape, window = 16384, (9046, 6077, 512, 512)
    r0, c0, h, w = window
    # the label cell each texel centre of the window lies in, counted here by hand: 48 cells over 16384 texels
    rows = ((np.arange(r0, r0 + h) + 0.5) * 48 / 16384).astype(int)
    cols = ((np.arange(c0, c0 + w) + 0.5) * 48 / 16384).astype(int)
    cells = region[np.ix_(rows, cols)]
    assert set(np.unique(cells).tolist()) == {7, 8, 10}
    np.testing.assert_array_equal(region_labels(region, shape, window), cells)
    # The heights say which regions lie where: only region k rough (the others and the off-face label 0 flat, no
    # pores, no blend beyond the bilinear reading of the label cells), the window is rough where k lies and
    # exactly flat where no label cell within one of the texel's holds k.
    seen = set()
    for k in range(1, 11):
        flat = SkinMicrostructure(roughness=0.0, pore_share=0.0)
        params = {j: flat for j in range(11)} | {k: SkinMicrostructure(roughness=0.3, pore_share=0.0)}
        hk = procedural_microstructure(shape, 15.0, params=params, region_map=region, window=window, smooth_mm=0.0)
        assert hk.shape == (h, w)
        near = maximum_filter(region == k, size=3)[np.ix_(rows, cols)]
        assert np.all(hk[cells == k] != 0), k
        assert np.all(hk[~near] == 0), k
        if np.any(hk != 0):
            seen.add(k)
    assert seen == {7, 8, 10}


def test_a_window_is_the_whole_maps_texels_there(monkeypatch):
    """A window of a map (several regions, pores, a deformation) equals the whole map's texels there, and a map
    generated in blocks of rows equals it generated at once: the waves are evaluated at the texels' positions and
    the pores drawn over the whole map, so a patch of a 16K face costs what its own size costs."""
    import facestats.acquire.synthetic.microstructure as micro

    rng = np.random.default_rng(0)
    region = rng.integers(0, 11, (6, 5))  # cells of about 50 texels: borders, blends and label 0 in the window
    params = {k: replace(p, pore_density_mm2=20.0) for k, p in micro.REGION_DEFAULTS.items()}  # ~400 pores
    kw = dict(params=params, region_map=region, seed=9, deformation=deformation_matrix((0.6, 0.8), 1.3))
    shape, (r0, c0, h, w) = (300, 280), (131, 97, 60, 75)
    whole = procedural_microstructure(shape, 15.0, **kw)
    assert whole.shape == shape
    part = procedural_microstructure(shape, 15.0, window=(r0, c0, h, w), **kw)
    assert part.shape == (h, w)
    scale = float(np.abs(whole).max())
    np.testing.assert_allclose(part, whole[r0 : r0 + h, c0 : c0 + w], rtol=0, atol=1e-5 * scale)
    monkeypatch.setattr(micro, "BLOCK_TEXELS", 2000)  # 7 rows a block: 43 blocks, pores across their borders
    np.testing.assert_allclose(procedural_microstructure(shape, 15.0, **kw), whole, rtol=0, atol=1e-5 * scale)
    with pytest.raises(FacestatsError, match=r"window must lie inside the 300 x 280 map"):
        procedural_microstructure(shape, 15.0, window=(250, 0, 60, 10))
    with pytest.raises(FacestatsError, match=r"window height must be an integer in \[1, inf\], got 0"):
        procedural_microstructure(shape, 15.0, window=(0, 0, 0, 10))
