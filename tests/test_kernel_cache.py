"""numba's kernel caches are cleared when any kernel module changes (facestats.core.kernel_cache)."""

import re
from pathlib import Path

import facestats
from facestats.core import kernel_cache
from facestats.core.kernel_cache import KERNEL_MODULES, STAMP, source_digest

PACKAGE = Path(facestats.__file__).resolve().parent


def test_every_module_with_kernels_is_listed():
    found = {
        p.relative_to(PACKAGE).as_posix()
        for p in PACKAGE.rglob("*.py")
        if re.search(r"numba\.(njit|jit|vectorize|guvectorize)|@njit", p.read_text(encoding="utf-8"))
    }
    assert found == set(KERNEL_MODULES)


def _package(tmp_path):
    for rel in KERNEL_MODULES:
        f = tmp_path / rel
        f.parent.mkdir(parents=True, exist_ok=True)
        f.write_text(f"# {rel}\n")
        cache = f.parent / "__pycache__"
        cache.mkdir(exist_ok=True)
        (cache / f"{f.stem}.kernel-12.py311.nbi").write_bytes(b"index")
        (cache / f"{f.stem}.kernel-12.py311.1.nbc").write_bytes(b"code")
        (cache / f"{f.stem}.cpython-311.pyc").write_bytes(b"bytecode")
    other = tmp_path / "model" / "fitting" / "kernels" / "__pycache__" / "unrelated.f-1.py311.nbi"
    other.write_bytes(b"not ours")
    return other


def _caches(root):
    return sorted(p.name for p in root.rglob("*.nb[ic]"))


def test_caches_are_cleared_once_and_again_after_a_change(tmp_path):
    refresh = kernel_cache.refresh_kernel_caches.__wrapped__  # the once-per-process memo bypassed
    other = _package(tmp_path)
    assert len(_caches(tmp_path)) == 2 * len(KERNEL_MODULES) + 1
    assert refresh(str(tmp_path)) is True  # no stamp yet: unknown caches are cleared
    assert _caches(tmp_path) == [other.name]  # a file of no kernel module stays
    assert (tmp_path / "__pycache__" / STAMP).read_text().strip() == source_digest(tmp_path)
    assert len(list(tmp_path.rglob("*.pyc"))) == len(KERNEL_MODULES)  # bytecode is not numba's
    # Unchanged sources: fresh caches are kept.
    lm = tmp_path / "model" / "fitting" / "kernels" / "__pycache__" / "lm.solve-3.py311.nbi"
    lm.write_bytes(b"new index")
    assert refresh(str(tmp_path)) is False and lm.exists()
    # A callee changes (not the caller's file): the caller's cache goes too.
    (tmp_path / "model" / "fitting" / "kernels" / "factors.py").write_text("# changed\n")
    assert refresh(str(tmp_path)) is True and not lm.exists()
    assert refresh(str(tmp_path)) is False


def test_the_installed_package_carries_its_digest():
    stamp = PACKAGE / "__pycache__" / STAMP
    assert not stamp.exists() or stamp.read_text().strip() == source_digest(PACKAGE)


def test_caches_outside_the_package_are_cleared_too(tmp_path, monkeypatch):
    """numba keeps the caches in NUMBA_CACHE_DIR when it is set, and in a user-wide folder when the package's
    __pycache__ cannot be written; only the package's own were cleared (an install red team)."""
    refresh = kernel_cache.refresh_kernel_caches.__wrapped__
    package = tmp_path / "pkg"
    _package(package)
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "numba-dir"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    places = kernel_cache.cache_places(package)
    want = [package / "__pycache__", tmp_path / "numba-dir", tmp_path / "xdg" / "numba"]
    assert [p[0].parent for p in places] == want
    for _, folders in places[1:]:
        for rel, folder in zip(KERNEL_MODULES, folders):
            folder.mkdir(parents=True, exist_ok=True)
            (folder / f"{Path(rel).stem}.kernel-12.py311.nbi").write_bytes(b"index")
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "elsewhere"))  # a user-wide folder without our caches
    assert refresh(str(package)) is True
    assert list((tmp_path / "elsewhere").iterdir()) == []  # is not written to
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert refresh(str(package)) is True
    assert _caches(package) == ["unrelated.f-1.py311.nbi"] and not _caches(tmp_path / "numba-dir")
    assert not _caches(tmp_path / "xdg")
    assert refresh(str(package)) is False  # each place carries the digest now
    (package / "io" / "deflate_numba.py").write_text("# changed\n")
    lm = places[1][1][KERNEL_MODULES.index("model/fitting/kernels/lm.py")] / "lm.solve-3.py311.nbi"
    lm.write_bytes(b"new index")
    assert refresh(str(package)) is True and not lm.exists()


def test_the_places_outside_the_package_are_where_numba_puts_its_caches(tmp_path, monkeypatch):
    from numba.core.caching import UserProvidedCacheLocator, UserWideCacheLocator

    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "numba-dir"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    places = kernel_cache.cache_places(PACKAGE)
    for i, rel in enumerate(KERNEL_MODULES):
        path = str(PACKAGE / rel)
        assert places[1][1][i] == tmp_path / "numba-dir" / UserProvidedCacheLocator.get_suitable_cache_subpath(path)
        assert places[2][1][i] == tmp_path / "xdg" / "numba" / UserWideCacheLocator.get_suitable_cache_subpath(path)
    import numba.misc.appdirs as appdirs

    assert appdirs.AppDirs(appname="numba", appauthor=False).user_cache_dir == str(tmp_path / "xdg" / "numba")


def test_a_cache_place_that_cannot_be_entered_is_left_alone(tmp_path, monkeypatch):
    """`import facestats` crashed with PermissionError where HOME (or NUMBA_CACHE_DIR) was another user's folder
    (a review): Path.is_dir raises there instead of returning False."""
    refresh = kernel_cache.refresh_kernel_caches.__wrapped__
    package = tmp_path / "pkg"
    _package(package)
    locked = tmp_path / "locked"
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(locked))
    real_is_dir = Path.is_dir

    def is_dir(self):
        if str(self).startswith(str(locked)):
            raise PermissionError(13, "Permission denied", str(self))
        return real_is_dir(self)

    monkeypatch.setattr(Path, "is_dir", is_dir)
    assert refresh(str(package)) is True  # the package's own caches are still cleared
    assert _caches(package) == ["unrelated.f-1.py311.nbi"]
