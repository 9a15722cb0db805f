"""The public API's docstrings: numpy-style sections that agree with the signatures.

Every function a module lists in ``__all__`` (and defines itself) that takes parameters documents them in a
numpy-style ``Parameters`` section, parsed with numpydoc's :class:`~numpydoc.docscrape.FunctionDoc`, the
parser Sphinx's numpydoc extension uses; the names documented are exactly the signature's, in its order
(``*args`` and ``**kwargs`` spelled so). So does every public method of the classes in ``__all__``, and each
class documents its constructor's parameters in its ``Parameters`` or (a dataclass's fields) ``Attributes``
section. A parameter renamed, added or removed without its docstring fails here.
"""

from __future__ import annotations

import enum
import importlib
import inspect
import pkgutil
import warnings

from numpydoc.docscrape import ClassDoc, FunctionDoc

import facestats


def _public_api():
    """``([(qualified name, function)], [(qualified name, class)])`` of every module's ``__all__``: its functions,
    its classes (not exceptions or enumerations: their members are their documentation) and their public methods."""
    functions, classes = [], []
    for info in pkgutil.walk_packages(facestats.__path__, "facestats."):
        if info.name.endswith("__main__"):
            continue
        module = importlib.import_module(info.name)
        for name in getattr(module, "__all__", ()):
            obj = getattr(module, name)
            if getattr(obj, "__module__", None) != module.__name__:
                continue
            if inspect.isfunction(obj):
                functions.append((f"{module.__name__}.{name}", obj))
            elif inspect.isclass(obj) and not issubclass(obj, (BaseException, enum.Enum)):
                classes.append((f"{module.__name__}.{name}", obj))
                for method, fn in vars(obj).items():
                    fn = fn.__func__ if isinstance(fn, (staticmethod, classmethod)) else fn
                    if not method.startswith("_") and inspect.isfunction(fn):
                        functions.append((f"{module.__name__}.{name}.{method}", fn))
    return functions, classes


FUNCTIONS, CLASSES = _public_api()


def _signature_names(func):
    """The parameter names as a numpy docstring spells them (``*args``, ``**kwargs``)."""
    names = []
    for p in inspect.signature(func).parameters.values():
        if p.name in ("self", "cls"):
            continue
        prefix = {p.VAR_POSITIONAL: "*", p.VAR_KEYWORD: "**"}.get(p.kind, "")
        names.append(prefix + p.name)
    return names


def _names(section):
    """The names of a ``Parameters``/``Attributes`` section; a line ``a, b : float`` documents both."""
    return [n.strip() for param in section for n in param.name.split(",")]


def _parsed(kind, obj, **config):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numpydoc warns of unknown sections and malformed headings
        return kind(obj, config=config)


def _documented_names(func):
    """The names of the ``Parameters`` section of ``func``'s docstring, and the parsed docstring."""
    doc = _parsed(FunctionDoc, func)
    return _names(doc["Parameters"]), doc


def _function_problem(name, func):
    """What is wrong with a function's or method's docstring, or None."""
    expected = _signature_names(func)
    try:
        documented, doc = _documented_names(func)
    except Warning as exc:
        return f"{name}: numpydoc cannot parse the docstring ({exc})"
    if not doc["Summary"]:
        return f"{name}: no summary line"
    if expected and not documented:
        return f"{name}: no numpy-style 'Parameters' section for {expected}"
    if documented != expected:
        return f"{name}: documents {documented}, signature has {expected}"
    return None


def _class_problem(name, cls):
    """What is wrong with a class docstring's account of its constructor, or None."""
    try:
        doc = _parsed(ClassDoc, cls, show_class_members=False)
    except Warning as exc:
        return f"{name}: numpydoc cannot parse the docstring ({exc})"
    if not doc["Summary"]:
        return f"{name}: no summary line"
    try:
        signature = inspect.signature(cls)
    except (TypeError, ValueError):  # no introspectable constructor
        return None
    expected = [p.name for p in signature.parameters.values() if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]
    documented = _names(doc["Parameters"]) + _names(doc["Attributes"])
    missing = [p for p in expected if p not in documented]
    if missing:
        return f"{name}: constructor parameters {missing} not in its Parameters or Attributes section"
    stale = [p for p in _names(doc["Parameters"]) if p not in expected]
    if stale:
        return f"{name}: documents parameters {stale} its constructor does not take"
    return None


def test_the_walk_finds_the_public_api():
    names = {name for name, _ in FUNCTIONS}
    assert len(FUNCTIONS) > 1000 and len(CLASSES) > 120
    assert {"facestats.model.dipole.reduced_albedo", "facestats.io.store.Store.subject"} <= names
    assert "facestats.errors.ValidationError" not in {name for name, _ in CLASSES}


# One test per kind, listing every problem (a parametrised case per function cost about 10 s of the suite).
def test_every_function_and_method_documents_its_parameters_as_its_signature_names_them():
    problems = [p for p in (_function_problem(name, func) for name, func in FUNCTIONS) if p]
    assert not problems, f"{len(problems)} docstrings:\n" + "\n".join(problems)


def test_every_class_documents_its_constructor():
    problems = [p for p in (_class_problem(name, cls) for name, cls in CLASSES) if p]
    assert not problems, f"{len(problems)} docstrings:\n" + "\n".join(problems)


def test_a_stale_or_missing_docstring_is_caught():
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

    def bare(x):
        """Bare."""
        return x

    class Point:
        """A point.

        Parameters
        ----------
        x : float
            Abscissa.
        """

        def __init__(self, x, y):
            self.x, self.y = x, y

    assert _function_problem("scale", scale) == "scale: documents ['x', 'gain'], signature has ['x', 'factor']"
    assert _function_problem("bare", bare) == "bare: no numpy-style 'Parameters' section for ['x']"
    assert "constructor parameters ['y']" in _class_problem("Point", Point)
