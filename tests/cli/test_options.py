"""Options of the command line given once (facestats.cli.options.Parser)."""

import pytest

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
