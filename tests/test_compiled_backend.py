"""Choosing between the compiled (numba) kernels and their numpy twins (facestats.core.compiled)."""

import pytest

from facestats.core import compiled
from facestats.errors import ValidationError


@pytest.fixture
def jit_disabled(monkeypatch):
    numba = pytest.importorskip("numba")
    compiled.numba_available.cache_clear()
    monkeypatch.setattr(numba.config, "DISABLE_JIT", True)
    yield
    monkeypatch.undo()
    compiled.numba_available.cache_clear()


def test_auto_takes_numba_where_it_compiles():
    pytest.importorskip("numba")
    compiled.numba_available.cache_clear()
    assert compiled.numba_available() and compiled.resolve_backend("auto") == "numba"
    assert compiled.resolve_backend("numpy") == "numpy"
    with pytest.raises(ValidationError, match="backend must be one of"):
        compiled.resolve_backend("cuda")


def test_with_the_jit_disabled_auto_takes_the_numpy_twins(jit_disabled):
    """NUMBA_DISABLE_JIT=1 would run the kernels as Python loops over every texel (hours), and the microstructure
    pass's LLVM intrinsic cannot run at all: "auto" takes numpy, and "numba" is refused saying why."""
    assert not compiled.numba_available()
    assert compiled.resolve_backend("auto") == "numpy"
    with pytest.raises(ValidationError, match="NUMBA_DISABLE_JIT"):
        compiled.resolve_backend("numba")
