"""Options of the command line given once (facestats.cli.options.Parser)."""

import argparse

import pytest

import facestats.cli
from facestats.cli import build_parser, main
from tests.helpers import run_cli


def test_an_option_given_twice_is_refused_naming_both_values():
    """argparse keeps the last value silently: `query --skin-type IV --skin-type V` answered for V alone (a
    fresh-user red team)."""
    r = run_cli("query", "--skin-type", "IV", "--skin-type", "V")
    assert r.returncode == 2 and r.stdout == ""
    assert "argument --skin-type: given twice (--skin-type 'IV', then --skin-type 'V'); give it once" in r.stderr


@pytest.mark.parametrize(
    "argv, option",
    [
        (["analyze", "pca", "--out", "a", "--out=b"], "--out"),  # nested subcommand, '=' spelling
        (["edit", "colour", "S001", "--target", "S006", "--target", "S007"], "--target"),
        (["build", "--store", "x.zarr", "--seed", "1", "--seed", "2"], "--seed"),
    ],
)
def test_every_subcommand_refuses_a_repeated_option(argv, option, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2 and f"argument {option}: given twice" in capsys.readouterr().err


def test_options_given_once_parse_as_before_and_leave_no_trace():
    args = build_parser().parse_args(["query", "--skin-type", "IV", "--gender", "f", "--format", "json"])
    assert (args.skin_type, args.gender, args.format) == ("IV", "f", "json")
    assert not [k for k in vars(args) if k.startswith("_")]
    again = build_parser().parse_args(["query", "--skin-type", "IV"])  # a new parse starts afresh
    assert again.skin_type == "IV"


@pytest.mark.parametrize("command", ["calibrate", "capture", "emulate", "edit", "microstructure"])
def test_a_command_group_without_its_subcommand_prints_its_usage_and_exits_2(command, capsys):
    """`facestats microstructure` alone exited 0 after its help, unlike the other command groups."""
    assert main([command]) == 2
    assert capsys.readouterr().out.startswith(f"usage: facestats {command} ")


def test_the_module_docstring_names_every_subcommand_of_the_groups_it_details():
    """The list of command groups in ``facestats.cli``'s docstring missed ``calibrate merge``."""
    doc = facestats.cli.__doc__
    groups = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices
    for command, parser in groups.items():
        assert f"``{command}" in doc, command
        subs = [a.choices for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        line = next((ln for ln in doc.splitlines() if f"``{command} " in ln), None)
        if subs and line is not None:  # a group listed with its subcommands lists all of them
            named = {w for part in line.split("``")[1::2] for w in part.split(" ", 1)[1].split("|")}
            assert named == set(subs[0]), (command, named)


def test_named_options_renames_the_longest_name_that_starts_the_message():
    """``light probe 'x' ...`` is ``--probe``'s message, not ``--light``'s (render named it ``--light probe``)."""
    from facestats.cli.options import named_options
    from facestats.errors import InsufficientDataError, ValidationError

    names = {"light": "--light", "light probe": "--probe"}  # the shorter first: the order must not matter
    with pytest.raises(ValidationError) as exc, named_options(**names):
        raise ValidationError("light probe 'x.hdr' does not exist")
    assert str(exc.value) == "--probe 'x.hdr' does not exist"
    with pytest.raises(InsufficientDataError) as exc, named_options(**names):  # the class is kept
        raise InsufficientDataError("light must be an integer in [0, 149], got 150")
    assert str(exc.value) == "--light must be an integer in [0, 149], got 150"
    with pytest.raises(ValidationError) as exc, named_options(**names):  # a name inside a word is not renamed
        raise ValidationError("lighting must be on, got 'off'")
    assert str(exc.value) == "lighting must be on, got 'off'"


def test_an_empty_store_value_is_named_as_the_option_by_every_command_that_opens_it(tmp_path):
    """open_store's message names its parameter ``path``; the commands name the option typed."""
    import scipy.io

    from tests.helpers import merl_dict, run_main

    scipy.io.savemat(tmp_path / "ts_data.mat", merl_dict())
    for argv in (("query",), ("info",), ("analyze", "pca"), ("serve",), ("import-merl", "ts_data.mat")):
        r = run_main(*argv, "--store", "", cwd=tmp_path)
        assert r.returncode == 2, (argv, r.stderr)
        assert "facestats: error: --store must name a store (a directory or a zip file), got ''" in r.stderr, argv
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ts_data.mat"]  # nothing written
