"""Fixtures shared by the store tests of this folder: a small store built once per module, and a copy per test."""

import pytest

from .helpers import copy_store, make_store, subject_digests


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """``(path, digests)`` of a store of three subjects, built once per test module (a module may define its own)."""
    path = make_store(tmp_path_factory.mktemp("base") / "s.zarr")
    return path, subject_digests(path)


@pytest.fixture
def store(base, tmp_path):
    """A copy of ``base`` for one test, with a sentinel tree beside it (:func:`helpers.copy_store`)."""
    return copy_store(base[0], tmp_path)
