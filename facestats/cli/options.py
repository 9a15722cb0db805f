"""Options several command groups share: numbers typed in ASCII, text and paths that may not be empty, how a
``--store`` value opens a store, and options given once.

A text or path option whose empty value has no meaning (``--plot ''``, ``relight ''``) is parsed by
:func:`non_empty`: argparse refuses ``''`` naming the option, where the commands took it for "not given" or
``pathlib.Path('')`` made it the current folder.

Numbers on the command line are ASCII: Python's ``int`` and ``float`` accept
the digits of every script (``int('١٤')`` is 14, ``float('١.٤')`` 1.4), which no
user of a command line means, so every numeric option is parsed by
:func:`ascii_int` or :func:`ascii_float` (argparse types) and every number
taken apart from a larger value (``64x32``, ``255,200,180``) by
:func:`number_option`; the one rule is :func:`ascii_number`.
"""

from __future__ import annotations

import argparse
import contextlib

from facestats.core.conventions import DEFAULT_STORE, TEXTURE_SAMPLE

__all__ = [
    "Parser",
    "add_store_option",
    "check_store_to_write",
    "store_path_option",
    "open_store_option",
    "check_apart_from_store",
    "ascii_number",
    "number_option",
    "ascii_int",
    "ascii_float",
    "non_empty",
    "named_options",
    "QUERY_FILTER_OPTIONS",
]

#: The namespace attribute in which :class:`_StoreOnce` notes the options given (removed after parsing).
_GIVEN = "_facestats_options_given"
#: The namespace attribute naming the parser of the command given (removed by :meth:`Parser.parse_args`).
_COMMAND_PARSER = "_facestats_command_parser"


class _StoreOnce(argparse.Action):
    """argparse's ``store``, refusing an option given twice: argparse keeps the last value silently, so
    ``query --skin-type IV --skin-type V`` answered for V alone (a fresh-user red team)."""

    def __call__(self, parser, namespace, values, option_string=None):
        if option_string is not None:  # positionals are counted by argparse itself
            given = namespace.__dict__.setdefault(_GIVEN, {})
            if self.dest in given:
                first, value = given[self.dest]
                parser.error(
                    f"argument {option_string}: given twice ({first} {value!r}, then {option_string} {values!r}); "
                    "give it once"
                )
            given[self.dest] = (option_string, values)
        setattr(namespace, self.dest, values)


class Parser(argparse.ArgumentParser):
    """:class:`argparse.ArgumentParser` whose single-valued options (the default ``store`` action) may be given
    once; its subcommands' parsers are of this class too (argparse makes them of the parent's class)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.register("action", None, _StoreOnce)
        self.register("action", "store", _StoreOnce)
        self.set_defaults(**{_COMMAND_PARSER: self})  # a subcommand's parser overrides its parent's: the deepest

    def parse_args(self, args=None, namespace=None):
        """:meth:`argparse.ArgumentParser.parse_args`, with unrecognised arguments reported by the parser of the
        command they were given to (its usage line: ``facestats query --skin-tpye IV`` shows ``query``'s options,
        not the list of commands).

        Parameters
        ----------
        args : list of str, optional
            The arguments to parse (default ``sys.argv[1:]``, as argparse).
        namespace : argparse.Namespace, optional
            The namespace to fill (default a new one).

        Returns
        -------
        argparse.Namespace
            The parsed options.
        """
        namespace, extras = self.parse_known_args(args, namespace)
        command = vars(namespace).pop(_COMMAND_PARSER, self)
        if extras:
            command.error("unrecognized arguments: " + " ".join(extras))
        return namespace

    def parse_known_args(self, args=None, namespace=None):
        """:meth:`argparse.ArgumentParser.parse_known_args`, dropping the record of the options given.

        Parameters
        ----------
        args : list of str, optional
            The arguments to parse (default ``sys.argv[1:]``, as argparse).
        namespace : argparse.Namespace, optional
            The namespace to fill (default a new one).

        Returns
        -------
        namespace : argparse.Namespace
            The parsed options, without the attribute in which each option given was noted.
        extras : list of str
            The arguments not recognised.
        """
        namespace, extras = super().parse_known_args(args, namespace)
        vars(namespace).pop(_GIVEN, None)
        return namespace, extras


#: What a number of each kind must look like, for messages.
_EXPECTED = {int: "an integer (ASCII digits 0-9)", float: "a number (ASCII digits 0-9)"}


def ascii_number(text, kind=int):
    """``kind(text)`` if ``text`` is a string of ASCII characters only that ``kind`` parses, else None.

    Parameters
    ----------
    text : str
        The number as typed.
    kind : {int, float}
        What to parse it as (``float`` keeps ``nan``/``inf`` spellings: ranges are checked by the command).

    Returns
    -------
    int, float or None
    """
    if not isinstance(text, str) or not text.isascii():
        return None
    try:
        return kind(text)
    except ValueError:
        return None


def number_option(text, kind, name: str):
    """:func:`ascii_number` of ``text``, or a :class:`~facestats.errors.ValidationError` naming ``name``.

    Parameters
    ----------
    text : str
        The number as typed.
    kind : {int, float}
    name : str
        The option (or part of one) it was given for, e.g. ``"--colour"``.

    Returns
    -------
    int or float
    """
    value = ascii_number(text, kind)
    if value is None:
        from facestats.errors import ValidationError

        raise ValidationError(f"{name} must be {_EXPECTED[kind]}, got {text!r}")
    return value


def _typed(text, kind):
    """:func:`ascii_number` of ``text``, or :class:`argparse.ArgumentTypeError` (argparse names the option)."""
    value = ascii_number(text, kind)
    if value is None:
        raise argparse.ArgumentTypeError(f"must be {_EXPECTED[kind]}, got {text!r}")
    return value


def ascii_int(text) -> int:
    """argparse ``type=`` of an integer option: ASCII only (``type=int`` also takes other scripts' digits).

    Parameters
    ----------
    text : str
        The value as typed (``int``'s syntax: sign, blanks and ``_`` separators allowed).

    Returns
    -------
    int

    Raises
    ------
    argparse.ArgumentTypeError
        ``text`` is not an integer typed in ASCII; argparse reports it naming the option (exit 2).
    """
    return _typed(text, int)


def ascii_float(text) -> float:
    """argparse ``type=`` of a real-valued option: ASCII only (``type=float`` also takes other scripts' digits).

    Parameters
    ----------
    text : str
        The value as typed (``float``'s syntax; ``nan`` and ``inf`` pass: ranges are checked by the command).

    Returns
    -------
    float

    Raises
    ------
    argparse.ArgumentTypeError
        ``text`` is not a number typed in ASCII; argparse reports it naming the option (exit 2).
    """
    return _typed(text, float)


def non_empty(text) -> str:
    """argparse ``type=`` of a text or path option that has no meaning when empty: ``text`` itself, or an error.

    Without it ``''`` reached commands that test ``if args.plot:`` (and took it for "not given": no plot, no
    filter) or turned it into the current folder (``pathlib.Path('')`` is ``.``) (a red team of the CLI).

    Parameters
    ----------
    text : str
        The value as typed.

    Returns
    -------
    str
        ``text``, unchanged.

    Raises
    ------
    argparse.ArgumentTypeError
        ``text`` is empty; argparse reports it naming the option (``argument --plot: must not be empty, got ''``,
        exit 2, before the command runs).
    """
    if text == "":
        raise argparse.ArgumentTypeError("must not be empty, got ''")
    return text


def add_store_option(
    parser,
    help="a store directory (X.zarr) or zip, or texture-sample (six subjects with 512² maps, built once into "
    "the cache); default (or 'default'): the store embedded in facestats",
):
    """``--store PATH`` (default None: the embedded store).

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The command's parser, to which the option is added.
    help : str
        The option's help text (default: what a ``--store`` value may be).

    Returns
    -------
    None
    """
    parser.add_argument("--store", default=None, metavar="PATH", help=help)


def add_mesh_scale_option(parser):
    """``--mesh-scale FACTOR`` (default None: 1), the unit of a ``--mesh`` file to mm, checked by the command through
    :func:`facestats.io.mesh.check_mesh_scale`.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The command's parser, to which the option is added.

    Returns
    -------
    None
    """
    parser.add_argument(
        "--mesh-scale",
        type=ascii_float,
        default=None,
        metavar="FACTOR",
        help="factor from the --mesh file's unit to mm (10 for cm, 1000 for m; default 1)",
    )


def store_path_option(value):
    """The store a ``--store`` value names: None (the embedded default) for None or ``default``, the texture
    sample's zip (built into the cache on first use) for ``texture-sample``, else ``value`` itself.

    Parameters
    ----------
    value : str or None
        The ``--store`` value.

    Returns
    -------
    str or None
        What :func:`facestats.open_store` takes as its ``path``.
    """
    if value == DEFAULT_STORE:
        return None
    if value == TEXTURE_SAMPLE:
        from facestats.pipeline.texture_sample import texture_sample

        return str(texture_sample())
    return value


def check_store_to_write(value, name: str):
    """``value`` of an option naming a directory store to write (``--out-store``, ``build --store``, ...), refused if
    it is a bare ``default`` or ``texture-sample``: every ``--store`` reads those names as the embedded stores, so a
    folder written under such a name would seem to vanish (a fresh-user red team: ``edit colour ... --out-store
    default`` wrote ``./default``, and ``info --store default`` then showed the embedded store).

    Parameters
    ----------
    value : str or None
        The option's value.
    name : str
        The option's name for the message, e.g. ``"--out-store"``.

    Returns
    -------
    str or None
        ``value`` itself.

    Raises
    ------
    ValidationError
        Naming the option and the value, with the ``./NAME`` spelling that writes such a folder.
    """
    from facestats.errors import ValidationError

    if value in (DEFAULT_STORE, TEXTURE_SAMPLE):
        what = "the embedded default store" if value == DEFAULT_STORE else "the texture sample"
        raise ValidationError(
            f"{name} must name a directory store to write, got {value!r}, which every --store reads as {what} "
            f"(read-only): to write a folder of that name, pass ./{value}"
        )
    return value


def check_apart_from_store(path, name: str, value) -> None:
    """Refuse an output ``path`` (option ``name``) that is the store a ``--store`` value names, or lies inside it.

    Writing there would mix files into the store (:func:`facestats.core.outputs.check_apart`).  The
    embedded default and the texture sample are zip files nothing can be written into: not looked up
    (so the texture sample is never built just for this check).

    Parameters
    ----------
    path : str or os.PathLike
        The output path.
    name : str
        The output's option name, e.g. ``"--out"``.
    value : str or None
        The ``--store`` value (None, ``default``, ``texture-sample`` or a URL: nothing is checked).

    Returns
    -------
    None

    Raises
    ------
    ValidationError
        ``path`` is the store or lies inside it (links resolved).
    """
    from facestats.core.outputs import check_apart

    if value is None or value in (DEFAULT_STORE, TEXTURE_SAMPLE):
        return
    check_apart(path, value, name, "the store")


def open_store_option(value, mode: str = "r"):
    """:func:`facestats.open_store` of what a ``--store`` value names (:func:`store_path_option`).

    Parameters
    ----------
    value : str or None
        The ``--store`` value.
    mode : {"r", "r+", "a"}
        :func:`facestats.open_store`'s mode (default read-only).

    Returns
    -------
    facestats.io.store.Store
        The open store (close it, or use it as a context manager).

    Raises
    ------
    StoreError
        As :func:`facestats.open_store` (a missing or unreadable store, ...).
    ValidationError
        A value that names no store (``''``), the message naming ``--store``.
    """
    from facestats.io.store import open_store

    with named_options(path="--store"):
        return open_store(store_path_option(value), mode=mode)


#: :func:`named_options` of the subset filters ``query`` and ``edit`` share: the words
#: :func:`facestats.core.conventions.parse_skin_type` and its siblings (``parse_gender``, ``parse_age``,
#: ``parse_condition``) start their messages with, and the options typed.
QUERY_FILTER_OPTIONS = {
    "skin type": "--skin-type",
    "gender": "--gender",
    "age range": "--age",
    "age": "--age",
    "condition": "--condition",
}


@contextlib.contextmanager
def named_options(**options):
    """Errors of the API call inside the block named by the command's options instead of its parameters.

    ``options`` maps parameter names to option names (``map_size="--size"``): a
    :class:`~facestats.errors.ValidationError` whose message starts with a parameter's name
    (``"map_size must be an integer in [8, inf], got 2"``) is raised again with the option's
    (``"--size must be ..."``); every other error passes unchanged.  The longest name that starts the message
    wins, so a subject a message names in words can be mapped beside a parameter its first word is
    (``**{"light probe": "--probe"}`` beside ``light="--light"``: ``"light probe 'x' does not exist"`` names
    ``--probe``, not ``--light``).

    Parameters
    ----------
    **options : str
        Option name (e.g. ``"--size"``) per parameter name.

    Returns
    -------
    contextlib.AbstractContextManager
        Use in a ``with`` statement; it yields None.

    Raises
    ------
    ValidationError
        Of the same class as the block's, the option's name in place of the parameter's.
    """
    from facestats.errors import ValidationError

    try:
        yield
    except ValidationError as exc:
        message = str(exc)
        for param, option in sorted(options.items(), key=lambda item: -len(item[0])):
            if message.startswith(f"{param} "):
                raise type(exc)(option + message[len(param) :]) from None
        raise
