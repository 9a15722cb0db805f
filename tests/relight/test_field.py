"""The reflectance-field data model and its zarr store: layouts, one bright texel, tiles, atomic writes."""

import numpy as np
import pytest

from facestats.errors import StoreError, ValidationError
from facestats.model.sphere import light_stage_directions, voronoi_solid_angles
from facestats.relight import field as fld


def _bright_field(grid=True):
    if grid:
        d, sa = light_stage_directions(8, 4)
        vals = np.zeros((4, 8, 5, 7, 3), np.float32)
        vals[2, 5, 3, 1, 2] = 9.5
    else:
        d = np.array([[0, 1, 0], [1, 0, 0], [0, 0, 1], [-1, 0, 0], [0, -0.6, -0.8]], float)
        vals = np.zeros((5, 5, 7, 3), np.float32)
        vals[4, 3, 1, 2] = 9.5
    return fld.make_field(vals, d, mask=np.ones((5, 7), bool), view=np.broadcast_to([0, 0, 1.0], (5, 7, 3)))


@pytest.mark.parametrize("grid", [True, False])
@pytest.mark.parametrize("dtype", ["float32", "float16"])
def test_one_bright_texel_survives_the_store(tmp_path, grid, dtype):
    f = _bright_field(grid)
    path = fld.write_field(tmp_path / "f.zarr", f, dtype=dtype, tile=4)
    g = fld.open_field(path)
    assert g["reflectance"].dims == f["reflectance"].dims
    vals = np.asarray(g["reflectance"].values)
    assert vals.dtype == np.dtype(dtype)
    idx = np.unravel_index(np.argmax(vals), vals.shape)
    assert idx == np.unravel_index(np.argmax(f["reflectance"].values), vals.shape)
    assert float(vals[idx]) == 9.5
    lights = idx[: 2 if grid else 1]
    assert np.array_equal(g["direction"].values[lights], f["direction"].values[lights])
    assert list(g["channel"].values) == ["R", "G", "B"]
    # A tile of all lights is one chunk: light dims whole, 4 × 4 pixels, 3 channels.
    chunks = g["reflectance"].data.chunksize
    assert chunks == f["reflectance"].shape[: 2 if grid else 1] + (4, 4, 3)


def test_solid_angles_default_to_exact_cells_or_voronoi():
    g = _bright_field(True)
    assert np.allclose(g["solid_angle"].values, light_stage_directions(8, 4)[1])
    lst = _bright_field(False)
    assert np.allclose(lst["solid_angle"].values, voronoi_solid_angles(lst["direction"].values))
    flat = fld.flatten_lights(g)
    assert flat["reflectance"].dims == ("light", "y", "x", "channel")
    d, sa, it = fld.light_table(g)
    assert np.allclose(flat["direction"].values, d) and d.shape == (32, 3) and np.allclose(it, 1)


def test_writes_are_atomic_and_never_overwrite_silently(tmp_path):
    f = _bright_field()
    p = fld.write_field(tmp_path / "f.zarr", f)
    with pytest.raises(StoreError, match="already exists"):
        fld.write_field(p, f)
    big = f.copy()
    big["reflectance"] = big["reflectance"] * 1e6
    with pytest.raises(ValidationError, match="overflow float16"):
        fld.write_field(p, big, dtype="float16", overwrite=True)
    assert float(fld.open_field(p)["reflectance"].max()) == 9.5  # the old store is intact
    assert sorted(x.name for x in tmp_path.iterdir()) == ["f.zarr"]  # no temporary left behind
    fld.write_field(p, big, overwrite=True)
    assert float(fld.open_field(p)["reflectance"].max()) == pytest.approx(9.5e6)


def test_tile_writer_matches_the_whole_write(tmp_path):
    f = _bright_field()
    d = f["direction"].values
    store = fld.FieldStore(tmp_path / "t.zarr", d, (5, 7), per_pixel={"mask": f["mask"].values}, tile=4)
    vals = f["reflectance"].values
    for ys, xs in [(slice(0, 4), slice(0, 4)), (slice(0, 4), slice(4, 7)), (slice(4, 5), slice(0, 4)),
                   (slice(4, 5), slice(4, 7))]:  # fmt: skip
        store.write(ys, xs, vals[:, :, ys, xs])
    g = store.close()
    assert np.array_equal(g["reflectance"].values, vals) and g["mask"].values.all()
    s2 = fld.FieldStore(tmp_path / "u.zarr", d, (5, 7))
    s2.abort()
    assert not (tmp_path / "u.zarr").exists() and len(list(tmp_path.iterdir())) == 1


@pytest.mark.parametrize("dtype", ["float32", "float16"])
def test_tiles_never_written_read_as_zero_and_relight(tmp_path, dtype):
    """The stage writes only the tiles that hold face pixels; the others read as the zarr fill value, which was NaN:
    relighting a 256² stage field from its store failed ("the relit value at pixel (y=0, x=0) ... is nan")."""
    from facestats.relight.lighting import uniform_probe
    from facestats.relight.relighting import relight

    f = _bright_field()
    store = fld.FieldStore(tmp_path / "t.zarr", f["direction"].values, (5, 7), tile=4, dtype=dtype)
    store.write(slice(0, 4), slice(0, 4), f["reflectance"].values[:, :, :4, :4])  # the one tile with the texel
    g = store.close()
    assert np.array_equal(g["reflectance"].values, f["reflectance"].values)  # zeros elsewhere, not NaN
    img = relight(g, probe=uniform_probe(8))
    assert np.all(img[4:] == 0) and np.all(img[:, 4:] == 0) and img[3, 1, 2] > 0


def test_bad_fields_are_refused():
    d, _ = light_stage_directions(8, 4)
    with pytest.raises(ValidationError, match="values must have shape"):
        fld.make_field(np.zeros((4, 8, 5, 3)), d)
    with pytest.raises(ValidationError, match=">= 0|must lie in"):
        fld.make_field(-np.ones((4, 8, 2, 2, 3)), d)
    with pytest.raises(ValidationError, match="lat-long light stage"):
        fld.make_field(np.zeros((4, 8, 2, 2, 3)), np.roll(d, 1, axis=1))
    with pytest.raises(ValidationError, match="reflectance"):
        fld.as_field(np.zeros(3))
    with pytest.raises(StoreError, match="does not exist"):
        fld.open_field("/nonexistent/field.zarr")
