"""Validation renders against known truth: a default subject's fitted model matches its re-simulated capture."""

from __future__ import annotations

import numpy as np
import pytest

import facestats
from facestats.errors import FacestatsError
from facestats.pipeline.validation import camera_rmse, default_capture, render_led, render_probe


@pytest.fixture(scope="module")
def case():
    with facestats.open_store() as st:
        ds = st.subject("S003")
    return ds, default_capture("S003")


@pytest.mark.slow
def test_a_truly_held_out_camera_matches_within_the_fit_figures(case):
    import json

    from facestats.pipeline import FitSettings, fit_subject

    ds, cap = case
    prov = json.loads(ds.attrs["provenance"])
    settings = FitSettings(**dict(prov["fit_settings"], exclude_cameras=(5,)))
    held = fit_subject(cap, prov["sigma_tr_avg"], settings)  # the default's fit, camera 5 never seen
    assert json.loads(held.attrs["provenance"])["fit_settings"]["exclude_cameras"] == [5]
    err = camera_rmse(held, cap, 5, lights=range(0, 150, 3))
    assert err < 0.03  # measured 2.05 % (1.90 % with camera 5 in the fit), 2026-12-07, cf69114


@pytest.mark.slow
def test_default_subject_matches_its_capture_within_the_fit_figures(case):
    ds, cap = case
    # Relative RMSE over a third of the LEDs in camera 5 (fit domain θ ≤ 80°); the fit issue reported ≈ 3 %.
    assert camera_rmse(ds, cap, 5, lights=range(0, 150, 3)) < 0.03
    r = render_led(ds, cap, 5, 20)
    assert r.relative_rmse < 0.05 and r.rendered.shape == r.reference.shape
    ok = np.isfinite(r.error).all(-1)
    assert ok.sum() > 50  # lit texels seen by camera 5 under LED 20: 82 of the default face's 857
    # The spatial transport blurs the diffuse term but keeps its energy: the image sums agree to 2 %.
    assert np.nansum(r.rendered) == pytest.approx(np.nansum(np.where(ok[..., None], r.reference, 0)), rel=0.02)


def test_micro_normals_are_used_for_the_specular_of_their_camera_when_asked(case):
    ds, cap = case
    tilted = ds.copy()
    mn = np.broadcast_to(tilted["normal"].values, (cap.dome.n_cameras,) + tilted["normal"].shape).copy()
    mn[5] = [0.0, 0.0, 1.0]  # a wrong micro-normal for camera 5 only
    tilted["micro_normal"] = (("camera", "v", "u", "component"), mn)
    plain = render_led(ds, cap, 5, 20).relative_rmse
    same = render_led(tilted, cap, 4, 20, micro_normals=True).relative_rmse
    assert same == pytest.approx(render_led(ds, cap, 4, 20).relative_rmse, rel=1e-6)
    assert render_led(tilted, cap, 5, 20, micro_normals=True).relative_rmse > plain
    # By default the specular lobe takes the fitted normal, whatever micro-normals the subject stores.
    assert render_led(tilted, cap, 5, 20).relative_rmse == plain
    assert camera_rmse(tilted, cap, 5, lights=[20]) == camera_rmse(ds, cap, 5, lights=[20])


def test_micro_normals_without_maps_or_not_a_bool_are_refused_by_name(case):
    ds, cap = case
    with pytest.raises(
        FacestatsError, match="micro_normals=True needs the subject's micro-normal maps, and subject 'S003'"
    ):
        render_led(ds, cap, 5, 20, micro_normals=True)
    with pytest.raises(FacestatsError, match="micro_normals=True needs"):
        render_probe(ds, cap, 5, np.ones((8, 16, 3)), samples=(2, 2), micro_normals=True)
    with pytest.raises(FacestatsError, match="micro_normals must be True or False, got 'yes'"):
        camera_rmse(ds, cap, 5, lights=[20], micro_normals="yes")


def test_a_built_subject_renders_closer_with_its_fitted_normal_than_with_its_micro_normals(tmp_path):
    """The stored micro-normals (the half vector of each view's largest sample, on the LED grid) are a median 9° from
    the fitted normal of a simulated subject, whose skin has no micro-geometry: rendered with them camera 5 under LED 20
    was 73 % off, with the fitted normal 2.8 % (size 24, 2026-12-07, cf69114; ``bench_export.bench_micro_normals``)."""
    from facestats.pipeline.build import build_store

    build_store(tmp_path / "b.zarr", map_size=16, subjects=["S001"], conditions=False, workers=1)
    with facestats.open_store(tmp_path / "b.zarr") as st:
        ds = st.subject("S001").load()
    assert "micro_normal" in ds.data_vars  # what `facestats build` keeps by default
    cap = default_capture(ds)
    plain = render_led(ds, cap, 5, 20).relative_rmse
    micro = render_led(ds, cap, 5, 20, micro_normals=True).relative_rmse
    assert plain < 0.06 and micro > 4 * plain


def test_a_capture_of_another_face_layout_is_refused_by_name(case):
    """Lumitexels outside the subject's face mean another face or UV layout (it failed on a zero normal before)."""
    ds, cap = case
    other = ds.copy()
    left = np.arange(ds.sizes["u"]) < ds.sizes["u"] // 2
    other["region"] = (("v", "u"), np.where(left, ds["region"].values, 0))  # half the face gone from the maps
    with pytest.raises(FacestatsError, match=r"capture \(of subject 'S003'\) does not fit subject 'S003': \d"):
        render_led(other, cap, 5, 20)


def test_probe_render_is_lit_and_shadowed(case):
    from facestats.io.probes import studio_probe
    from facestats.model.sphere import latlong_directions

    ds, cap = case
    probe = studio_probe(16)
    lit = render_probe(ds, cap, 5, probe, samples=(8, 16))
    assert lit.reference is None and np.nanmin(lit.rendered) >= 0 and np.nanmean(lit.rendered) > 0
    # Under light from everywhere every lumitexel the camera sees is lit: no black pixel (lumitexels facing away
    # from the camera were rendered black into the image until 2026-12-07).
    assert np.nanmin(render_probe(ds, cap, 5, np.ones((16, 32, 3)), samples=(8, 16)).rendered) > 0
    # A probe dark everywhere but behind the head lights almost nothing the camera sees (rims only).
    d = latlong_directions(16, 32)
    back = np.where((d[..., 2] < -0.5)[..., None], probe, 0)
    assert np.nansum(render_probe(ds, cap, 5, back, samples=(8, 16)).rendered) < 0.05 * np.nansum(lit.rendered)
    with pytest.raises(FacestatsError, match="camera must be"):
        render_led(ds, cap, 99, 0)


def test_a_splatted_pixel_is_the_mean_of_its_finite_lumitexels():
    """An e2e red team: the last lumitexel projecting into a pixel won, NaN or not, so a sample invalid in the camera
    blanked a valid one (11 of 409 such pixels of default S030, camera 11, LED 5)."""
    from types import SimpleNamespace

    from facestats.acquire.dome import default_dome
    from facestats.pipeline.render import camera_image

    dome = default_dome()
    corners = [[-60.0, -80.0, 60.0], [60.0, -80.0, 60.0], [-60.0, 80.0, 60.0], [60.0, 80.0, 60.0]]
    centre = [[0.0, 0.0, 90.0]] * 4  # four lumitexels at one point: one pixel
    pos = np.array(corners + centre)
    capture = SimpleNamespace(dome=dome, array=lambda name: pos)
    values = np.array([[1.0, 2.0, 3.0]] * 4 + [[np.nan] * 3, [2.0, 4.0, 6.0], [4.0, 8.0, 10.0], [np.nan] * 3])
    img = camera_image(values, capture, 11, 0)
    finite = np.isfinite(img).all(-1)
    assert finite.sum() == 5  # the four corners and the centre, whatever order the lumitexels come in
    np.testing.assert_allclose(np.sort(img[finite][:, 0]), [1, 1, 1, 1, 3])  # the centre: the mean of 2 and 4
    np.testing.assert_allclose(img[finite][img[finite][:, 0] == 3], [[3.0, 6.0, 8.0]])
    np.testing.assert_array_equal(camera_image(values, capture, 11, 0, channel=2)[finite], img[finite][:, 2])
    assert not np.isfinite(camera_image(np.full((8, 3), np.nan), capture, 11, 0)).any()


@pytest.mark.slow
def test_probe_radiance_agrees_with_the_relighting_stage_where_the_camera_sees_the_face():
    """Two renders of one subject under the same 256 directional lights: the validation path (lumitexels, dipole
    transport between them, shadow maps at the lumitexels) and the relighting stage's direct render (the mesh
    rasterised into a pinhole camera at the dome camera's position, local transport, visibility interpolated
    from the mesh's vertices), sampled at the pixels the lumitexels project to.  Their sums over the lumitexels
    the camera sees agree within 1 % under a uniform probe and 2.5 % under one lit only from more than 60° above
    the frontal axis, where every light grazes the face and shadows cover much of it (measured 2026-12-07 on
    default S001, camera 5: −0.3 / −0.2 / −0.2 % and +1.3 / +1.6 / +1.8 %; 82 % of the lumitexels in the
    camera's frame are seen).  An e2e red team found the two apart under light from above: the validation path
    lit the face from 2 m instead of from afar, and rendered the lumitexels hidden from the camera into the
    image."""
    from facestats.model.sphere import latlong_directions, median_cut_light_samples
    from facestats.pipeline.validation import face_view, probe_radiance
    from facestats.relight.camera import StageCamera
    from facestats.relight.stage import render_subject

    with facestats.open_store() as st:
        ds = st.subject("S001")
    view = face_view(ds)
    d = latlong_directions(64, 128)
    pos = view.array("position").astype(np.float64)
    eye = view.dome.camera_position[5]
    cam = StageCamera(eye, pos.mean(0), 16.0, 384)
    xyz = (pos - eye) @ cam.rotation.T
    px = np.floor(cam.focal * xyz[:, :2] / xyz[:, 2:] + cam.size / 2).astype(int)
    above = np.where(d[..., 1:2] > np.sin(np.radians(60)), np.ones(3), 0)
    for name, probe, tolerance in (("uniform", np.ones((64, 128, 3)), 0.01), ("above", above, 0.025)):
        values, _ = probe_radiance(ds, view, 5, probe, samples=256)
        seen = np.isfinite(values).all(1)
        assert 0.7 < seen.mean() < 0.95, name  # the far side of the face is not rendered
        directions, power = median_cut_light_samples(probe, 256)
        image, mask = render_subject(ds, power, directions, cam)
        on_mask = mask[px[seen, 1], px[seen, 0]]
        assert on_mask.mean() > 0.95, name  # the stage's mask ends at the face's texels, a few lumitexels short
        both = np.flatnonzero(seen)[on_mask]
        stage = image[px[both, 1], px[both, 0]].astype(np.float64)
        np.testing.assert_allclose(values[both].sum(0) / stage.sum(0), 1, atol=tolerance, err_msg=name)
