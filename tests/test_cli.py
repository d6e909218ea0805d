"""The command line: help texts, sub-commands, exit status on bad input."""

import subprocess
import sys

import pytest

from nurbscan.cli import COMMANDS, build_parser, main


def test_every_stage_has_a_subcommand_with_help(capsys):
    parser = build_parser()
    for name in COMMANDS:
        with pytest.raises(SystemExit) as info:
            parser.parse_args([name, "--help"])
        assert info.value.code == 0
        assert len(capsys.readouterr().out) > 80, name


def test_console_entry_point_runs():
    out = subprocess.run([sys.executable, "-m", "nurbscan", "--help"], capture_output=True,
                         text=True, check=True).stdout
    for name in COMMANDS:
        assert name in out


def test_unknown_command_is_refused(capsys):
    with pytest.raises(SystemExit) as info:
        main(["no-such-stage"])
    assert info.value.code == 2


def test_demo_help_names_what_the_demo_writes(capsys):
    """Every stage is built: the demo's help names its products, no stage 'not yet built'."""
    with pytest.raises(SystemExit):
        build_parser().parse_args(["demo", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    for product in ("pattern.png", "scan/", "calib.json", "model/", "teapot.glb",
                    "evaluation.json", "report.html"):
        assert "DIR/" + product in out, product
    assert "not yet" not in out and "not built" not in out
