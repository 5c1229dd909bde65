"""The command's error contract: input errors exit 2, internal failures exit 1, both in one line;
a mistyped option is refused in the sub-command's own usage."""

import pytest

from inertia_gym import cli


def _boom(args):
    raise ZeroDivisionError("float division by zero")


def test_an_internal_failure_is_one_line_with_exit_1(monkeypatch, capsys):
    monkeypatch.delenv(cli.DEBUG_VARIABLE, raising=False)
    parser = cli.build_parser()
    args = parser.parse_args(["identify", "x.csv"])
    monkeypatch.setattr(cli, "build_parser", lambda: _Fixed(args))
    assert cli.main([]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    assert "internal error: ZeroDivisionError" in err and cli.DEBUG_VARIABLE in err


def test_debug_variable_shows_the_traceback(monkeypatch):
    monkeypatch.setenv(cli.DEBUG_VARIABLE, "1")
    args = cli.build_parser().parse_args(["identify", "x.csv"])
    monkeypatch.setattr(cli, "build_parser", lambda: _Fixed(args))
    with pytest.raises(ZeroDivisionError):
        cli.main([])


class _Fixed:
    """A parser stand-in that returns parsed arguments whose command raises."""

    def __init__(self, args):
        args.func = _boom
        self.args = args

    def parse_known_args(self, argv):
        return self.args, []


def test_a_mistyped_option_is_refused_with_the_sub_commands_usage(capsys):
    with pytest.raises(SystemExit) as stopped:
        cli.main(["identify", "x.csv", "--ouput", "runs/x"])
    assert stopped.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("usage: inertia-gym identify ") and "--out DIR" in err
    assert err.rstrip().endswith("error: unrecognized arguments: --ouput runs/x")
