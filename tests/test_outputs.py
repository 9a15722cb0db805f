"""``facestats.core.outputs.check_apart`` with URLs (``OutputSet`` and the output checks: tests/reliability).

A ``file://`` store, which :func:`facestats.open_store` opens, was skipped as a URL (``edit --store file:///d/s.zarr
--images /d/s.zarr/imgs`` passed the check), and a ``file://`` output was resolved as the local folder ``./file:/…``.
An ``s3://`` output was resolved as ``./s3:/…`` too: refused when run from inside the store.
"""

import os

import pytest

from facestats.core.outputs import check_apart
from facestats.errors import ValidationError


def test_a_file_url_stands_for_its_path_on_either_side(tmp_path):
    store = tmp_path / "s.zarr"
    store.mkdir()
    with pytest.raises(ValidationError, match="--images must lie outside the store"):
        check_apart(store / "imgs", f"file://{store}", "--images")
    with pytest.raises(ValidationError, match="--out-store must lie outside the source store"):
        check_apart(f"file://{store}/inner.zarr", store, "--out-store", "the source store", same=True)
    check_apart(f"file://{store}", store, "--out-store", "the source store", same=True)  # the store itself
    check_apart(f"file://{tmp_path}/other.zarr", f"file://{store}", "--out-store")


def test_a_remote_url_is_not_a_local_path_wherever_the_command_runs(tmp_path, monkeypatch):
    store = tmp_path / "s.zarr"
    store.mkdir()
    monkeypatch.chdir(store)  # s3://bucket/x resolved as ./s3:/bucket/x lay inside the store
    check_apart("s3://bucket/out.zarr", store, "--out-store", same=True)
    check_apart(store / "imgs", "s3://bucket/s.zarr", "--images")
    assert os.listdir(store) == []


def test_a_path_that_is_none_is_still_refused_by_name():
    with pytest.raises(ValidationError, match="--out must be a file system path, got None"):
        check_apart(None, "/tmp/s.zarr", "--out")
