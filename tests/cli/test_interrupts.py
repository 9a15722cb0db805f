"""Ctrl-C is reported as an interrupt (exit 130), also when compiled code turns it into another error."""

import pytest

from facestats import cli
from facestats.cli import build as build_cli
from facestats.cli.interrupts import is_interrupt


def _disguised_interrupt():
    """What numba raises when a KeyboardInterrupt lands in a compiled function."""
    try:
        raise KeyboardInterrupt
    except KeyboardInterrupt:
        raise SystemError("CPUDispatcher(<function f>) returned a result with an exception set")


def test_is_interrupt_follows_the_chain():
    with pytest.raises(SystemError) as info:
        _disguised_interrupt()
    assert is_interrupt(info.value) and is_interrupt(KeyboardInterrupt())
    assert not is_interrupt(SystemError("a real one")) and not is_interrupt(ValueError())
    loop = ValueError("cycle")
    loop.__context__ = RuntimeError()
    loop.__context__.__context__ = loop
    assert not is_interrupt(loop)


def test_a_disguised_interrupt_exits_130_not_as_a_bug(monkeypatch, capsys):
    monkeypatch.setattr(build_cli, "_build_command", lambda args: _disguised_interrupt())
    assert cli.main(["build", "--store", "never-written.zarr"]) == 130
    err = capsys.readouterr().err
    assert "build interrupted" in err and "bug" not in err
    parser = cli.build_parser()
    args = parser.parse_args(["demo"])
    monkeypatch.setattr(parser, "parse_args", lambda argv: args)
    monkeypatch.setattr(cli, "build_parser", lambda: parser)
    monkeypatch.setattr(args, "func", lambda a: _disguised_interrupt())
    assert cli.main([]) == 130
    err = capsys.readouterr().err
    assert "interrupted" in err and "bug" not in err
