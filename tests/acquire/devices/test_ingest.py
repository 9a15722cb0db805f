"""An emulated session's folder is what ``facestats ingest`` reads: the ingested radiance is the simulator's."""

import json

import numpy as np
import pytest

from facestats.acquire.devices.lab import emulated_dome, emulated_sensor
from tests.acquire.devices.helpers import run_capture


@pytest.mark.slow
def test_dome_and_sensor_sessions_ingest_into_a_subject_with_the_simulated_radiance(tmp_path):
    from facestats.acquire.ingest import open_ingested
    from facestats.io import open_store
    from facestats.pipeline import FitSettings
    from facestats.pipeline.photographs import ingest_subject

    lab, out = tmp_path / "lab", tmp_path / "capture"
    dome = emulated_dome("S011", tmp_path / "hot", lab, resolution=96, leds=6, cameras=4, seed=1)
    try:
        run_capture(dome, lab, tmp_path / "hot", out)
    finally:
        dome.stop()
    sensor = emulated_sensor("S011", tmp_path / "shot", lab)
    try:
        run_capture(sensor, lab, tmp_path / "shot", out, kind="sensor")
    finally:
        sensor.stop()
    few = FitSettings(min_samples=4, micro_normals=False)  # 4 cameras × 6 LEDs: at most 24 samples a lumitexel
    report = ingest_subject(
        out,
        lab / "face.obj",
        out / "dome.json",
        tmp_path / "s.zarr",
        "S011",
        regions=lab / "face.regions.npy",
        workers=1,
        settings=few,
        min_footprint_px=1,
        progress=False,
    )
    assert "ingested S011" in report.to_text()
    with open_store(tmp_path / "s.zarr") as st:
        ds = st.subject("S011")
    assert ds.attrs["age"] == dome.scene.truth.age and "albedo" in ds
    measured = np.asarray(json.loads((out / "sensor.json").read_text())["profile"])
    np.testing.assert_array_equal(ds["sensor_profile"].values, measured)  # the sensor session's merged bracket
    cap = open_ingested(tmp_path / "s.zarr.ingest" / "S011" / "capture.zarr")
    a, b = cap.array("radiance").astype(np.float64), dome.scene.radiance.astype(np.float64)
    both = np.isfinite(a) & np.isfinite(b) & (b > 0.01)
    assert both.sum() > 500
    ratio = a[both] / b[both]
    assert abs(np.median(ratio) - 1) < 0.01 and np.percentile(np.abs(ratio - 1), 75) < 0.05
