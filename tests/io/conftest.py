"""Fixtures shared by the tests of facestats.io."""

import pytest


@pytest.fixture(scope="module")
def default_subject():
    """Subject S001 of the embedded default store (maps at 48², on ICT-FaceKit's face)."""
    import facestats

    with facestats.open_store() as st:
        return st.subject("S001")
