"""The public API's docstrings: numpy-style sections that agree with the signatures.

Every function a module lists in ``__all__`` (and defines itself) that takes parameters documents them in a
numpy-style ``Parameters`` section, parsed with numpydoc's :class:`~numpydoc.docscrape.FunctionDoc`, the
parser Sphinx's numpydoc extension uses; the names documented are exactly the signature's, in its order
(``*args`` and ``**kwargs`` spelled so). A parameter renamed, added or removed without its docstring fails here.
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import warnings

import pytest
from numpydoc.docscrape import FunctionDoc

import facestats

# ``main(argv)`` of the command-line entry point: its documentation is ``facestats --help``.
EXEMPT = {("facestats.cli", "main")}


def _public_functions():
    """``[(module name, function name, function)]`` for every function of every module's ``__all__``."""
    found = []
    for info in pkgutil.walk_packages(facestats.__path__, "facestats."):
        if info.name.endswith("__main__"):
            continue
        module = importlib.import_module(info.name)
        for name in getattr(module, "__all__", ()):
            obj = getattr(module, name)
            if inspect.isfunction(obj) and obj.__module__ == module.__name__ and (module.__name__, name) not in EXEMPT:
                found.append((module.__name__, name, obj))
    return found


FUNCTIONS = _public_functions()


def _signature_names(func):
    """The parameter names as a numpy docstring spells them (``*args``, ``**kwargs``)."""
    names = []
    for p in inspect.signature(func).parameters.values():
        if p.name in ("self", "cls"):
            continue
        prefix = {p.VAR_POSITIONAL: "*", p.VAR_KEYWORD: "**"}.get(p.kind, "")
        names.append(prefix + p.name)
    return names


def _documented_names(func):
    """The names of the ``Parameters`` section; a line ``a, b : float`` documents both."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numpydoc warns of unknown sections and malformed headings
        doc = FunctionDoc(func, config={})
    names = []
    for param in doc["Parameters"]:
        names.extend(n.strip() for n in param.name.split(","))
    return names, doc


def test_the_walk_finds_the_public_api():
    modules = {m for m, _, _ in FUNCTIONS}
    assert len(FUNCTIONS) > 700 and len(modules) > 150
    assert ("facestats.model.dipole", "reduced_albedo") in {(m, n) for m, n, _ in FUNCTIONS}


@pytest.mark.parametrize("module, name, func", FUNCTIONS, ids=[f"{m}.{n}" for m, n, _ in FUNCTIONS])
def test_parameters_section_matches_signature(module, name, func):
    expected = _signature_names(func)
    documented, doc = _documented_names(func)
    if expected:
        assert documented, f"{module}.{name}: no numpy-style 'Parameters' section for {expected}"
    assert documented == expected, f"{module}.{name}: documents {documented}, signature has {expected}"
    assert doc["Summary"], f"{module}.{name}: no summary line"


def test_a_stale_docstring_is_caught():
    def scale(x, factor=2.0):
        """Scale.

        Parameters
        ----------
        x : float
            Value.
        gain : float
            Old name of the factor.
        """
        return x * factor

    assert _documented_names(scale)[0] == ["x", "gain"] != _signature_names(scale)
