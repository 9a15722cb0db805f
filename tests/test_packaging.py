"""The installed package holds every file of the checkout's package.

The tests run the checkout (tests/conftest.py puts it first on every child process's path), so a file that
``pip install .`` leaves out (package data missing from ``[tool.setuptools.package-data]``) would go unnoticed
by them; this test compares the two trees.  Skipped for editable installs, which install no files.
"""

import pathlib
import sysconfig

import pytest

REPO = pathlib.Path(__file__).resolve().parent.parent


def _files(root: pathlib.Path) -> set:
    return {
        str(p.relative_to(root))
        for p in root.rglob("*")
        if p.is_file() and "__pycache__" not in p.parts and p.suffix not in (".pyc", ".nbi", ".nbc")
    }


def test_the_installed_package_holds_every_file_of_the_checkout():
    installed = pathlib.Path(sysconfig.get_paths()["purelib"]) / "facestats"
    if not installed.is_dir() or installed.resolve() == (REPO / "facestats").resolve():
        pytest.skip("facestats is not installed as files in site-packages (an editable install)")
    checkout = _files(REPO / "facestats")
    assert len(checkout) > 100
    missing = sorted(checkout - _files(installed))
    assert not missing, f"pip install leaves out {missing[:10]}: add them to [tool.setuptools.package-data]"
