"""Whose fault: bad input is the user's (one line ``strain-comp: error: ...``, exit 2), any
other exception the program's (one line ``strain-comp: internal error: ...`` naming the
file that holds the traceback, exit 70; ``--debug``: the traceback on stderr). The parser
is assembled from one module per command, each with ``add_arguments`` and ``run``."""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from pathlib import Path

import pytest

from strain_comp import cli
from strain_comp.cli import COMMANDS, EXIT_BUG, build_parser, main
from strain_comp.errors import InputError

ROOT = Path(__file__).resolve().parents[2]


def _broken(args: argparse.Namespace) -> int:
    return {"a": 1}["b"]  # a KeyError: the program's own fault


def test_a_program_error_is_one_line_naming_its_traceback(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(cli.simulate, "run", _broken)
    assert main(["simulate", "--list"]) == EXIT_BUG == 70
    captured = capsys.readouterr()
    lines = captured.err.splitlines()
    assert len(lines) == 1 and captured.out == ""
    found = re.fullmatch(r"strain-comp: internal error: KeyError: 'b' \(a bug: the traceback "
                         r"is in (\S+\.log); please report it\)", lines[0])
    assert found, lines[0]
    log = Path(found.group(1))
    try:
        text = log.read_text(encoding="utf-8")
    finally:
        log.unlink()
    assert "Traceback (most recent call last)" in text and "in _broken" in text
    assert text.rstrip().endswith("KeyError: 'b'")


def test_debug_shows_the_traceback_and_writes_no_file(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(cli.simulate, "run", _broken)
    assert main(["simulate", "--list", "--debug"]) == 70
    err = capsys.readouterr().err
    assert "Traceback (most recent call last)" in err and "in _broken" in err
    assert err.splitlines()[-1] == ("strain-comp: internal error: KeyError: 'b' (a bug: the "
                                    "traceback is above; please report it)")


def test_errors_of_the_user_stay_one_line_and_exit_2(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    def refused(args: argparse.Namespace) -> int:
        raise InputError("--seed 3: not today")

    monkeypatch.setattr(cli.simulate, "run", refused)
    assert main(["simulate", "--list"]) == 2
    assert capsys.readouterr().err == "strain-comp: error: --seed 3: not today\n"
    assert main(["simulate", "--seed", "x"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("strain-comp: error: simulate: argument")


def test_an_interrupt_is_130(monkeypatch: pytest.MonkeyPatch,
                             capsys: pytest.CaptureFixture[str]) -> None:
    """Ctrl-C: exit 130 and one line (``strain-comp node`` interrupted before the node's
    own handlers are in place says it too)."""
    def interrupted(args: argparse.Namespace) -> int:
        raise KeyboardInterrupt

    monkeypatch.setattr(cli.simulate, "run", interrupted)
    capsys.readouterr()
    assert main(["simulate", "--list"]) == 130
    assert capsys.readouterr().err == "strain-comp: interrupted\n"


def test_the_parser_is_assembled_from_one_module_per_command() -> None:
    """Each command's module gives its name, help, flags and ``run``; the parser lists them
    in that order, each with ``--quiet`` and ``--debug``."""
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert list(sub.choices) == [c.NAME for c in COMMANDS] == [
        "simulate", "import-csv", "fit", "start", "evaluate", "replay", "diagnose", "recalibrate",
        "node", "play"]
    for command in COMMANDS:
        p = sub.choices[command.NAME]
        assert p.get_default("func") is command.run
        assert {"--quiet", "--debug"} <= set(p._option_string_actions)
        assert Path(sys.modules[command.__name__].__file__ or "").parent == ROOT / \
            "strain_comp" / "cli"


def test_version_and_help_import_no_command_machinery(
        capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    """``--version`` and ``--help`` load no numpy and no model (a fast start); ``fit
    --help`` builds its options list only when asked."""
    probe = ("import sys; from strain_comp.cli import main; main([{}]); "
             "print(sorted(m for m in sys.modules if m.split('.')[0] in "
             "('numpy', 'scipy', 'numba') or m.startswith('strain_comp.models')))")
    for argv in ('"--version"', '"--help"'):
        out = subprocess.run([sys.executable, "-c", probe.format(argv)], capture_output=True,
                             text=True, check=True, cwd=ROOT,
                             env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
        assert out.stdout.strip().splitlines()[-1] == "[]", argv
    monkeypatch.setenv("COLUMNS", "80")  # the help's width, as in a pipe
    capsys.readouterr()
    assert main(["fit", "--help"]) == 0
    from strain_comp.offline.options import describe_options

    assert capsys.readouterr().out.rstrip().endswith(
        describe_options() + "\n\nexample:\n  strain-comp fit run1.mcap run2.mcap run3.mcap "
        "--model auto --sensor s1 --out s1.yaml")


def test_names_with_mathtext_or_undecodable_bytes_are_drawn_as_plain_text(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import dataclasses
    import json
    import os

    import strain_comp as sc
    from strain_comp.io.recording import write_recordings

    run = sc.read_recordings(ROOT / "bags" / "demo_rates.mcap")["s1"]
    cal = sc.load_calibration(ROOT / "config" / "demo_calibration.yaml").sensors["s1"]
    name = "s$^$_{x"  # not valid mathtext: matplotlib refuses to draw it as math
    bag = tmp_path / os.fsdecode(b"run\xff$x^2$.mcap")  # a surrogate in the bag's name
    write_recordings({name: sc.Recording.from_arrays(run.t[:2000], run.r[:2000],
                                                     run.s[:2000], name=name)}, bag)
    sc.save_calibration(sc.Calibration({name: dataclasses.replace(cal, name=name)}),
                        tmp_path / "cal.yaml")
    out = {k: tmp_path / f"out.{k}" for k in ("json", "html")}
    assert main(["evaluate", str(bag), "--calibration", str(tmp_path / "cal.yaml"), "-q",
                 "--json", str(out["json"]), "--plots", str(tmp_path / "plots"),
                 "--report", str(out["html"])]) == 0, capsys.readouterr().err
    assert name in json.loads(out["json"].read_text())["sensors"]
    assert len(list((tmp_path / "plots").glob("*.png"))) == 4
    page = out["html"].read_text(encoding="utf-8")
    assert "run\\udcff$x^2$.mcap" in page and page.count("data:image/png;base64,") == 4
