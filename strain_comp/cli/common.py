"""What every command of the command line shares: the parser's one-line errors, notes and
the results stream, input and output path checks, JSON writing, the flags several commands
take (docs/design.md, "Command line")."""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
from collections.abc import Callable, Sequence
from typing import NoReturn, Protocol, TextIO

from strain_comp.errors import InputError, StrainCompError
from strain_comp.io.atomic import check_output, write_text
from strain_comp.io.inputs import existing

PROG = "strain-comp"
OUT_OF_RANGE_HINT = ("samples out of the calibrated range: if the sensor's rest level or "
                     "sensitivity moved, start the session on a stretch and back "
                     "(strain-comp start)")


class Command(Protocol):
    """A command's module: its name, its help, its flags and what it does."""

    NAME: str
    SUMMARY: str
    DESCRIPTION: str
    EXAMPLE: str

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        """The command's arguments and flags (besides ``--quiet`` and ``--debug``)."""

    def run(self, args: argparse.Namespace) -> int:
        """Do the command; returns the exit code. Bad input raises ``StrainCompError``."""


class UsageError(StrainCompError):
    """A command line argparse cannot parse (printed as one line, exit code 2)."""


class Parser(argparse.ArgumentParser):
    """argparse with one-line usage errors; ``notes()`` adds text to the help when printed."""

    notes: Callable[[], str] | None = None

    def error(self, message: str) -> NoReturn:
        command = self.prog.removeprefix(PROG).strip()
        hint = f"see {self.prog} --help"
        raise UsageError(f"{command + ': ' if command else ''}{message} ({hint})")

    def exit(self, status: int = 0, message: str | None = None) -> NoReturn:
        if status != 0 or message:
            raise UsageError(message or f"exit status {status}")
        raise SystemExit(0)

    def format_help(self) -> str:
        if self.notes is not None:
            self.epilog = self.notes() + "\n\n" + (self.epilog or "")
            self.notes = None
        return super().format_help()


def err(line: str) -> None:
    """One line on stderr."""
    print(line, file=sys.stderr)


def note(args: argparse.Namespace, line: str) -> None:
    """A note on stderr, unless ``--quiet``."""
    if not getattr(args, "quiet", False):
        err(line)


def results(args: argparse.Namespace) -> TextIO:
    """Where the command's table goes."""
    dash = "-" in (getattr(args, "json", None), getattr(args, "csv", None))
    return sys.stderr if dash else sys.stdout


def bag(path: str, what: str = "bag") -> str:
    """An input bag: an MCAP file, a ``.db3`` file or a rosbag2 directory."""
    return existing(path, what, directory=True)


def output(path: str, inputs: Sequence[str | None]) -> str:
    """``path`` if it may be written: not one of ``inputs``, not a non-regular file."""
    check_output(path, [i for i in inputs if i is not None])
    return path


def write_json(path: str, data: object, inputs: Sequence[str]) -> None:
    """JSON to ``path`` (atomically) or to stdout for ``-``."""
    from strain_comp.offline.evaluation import json_safe  # numpy: loaded when writing only

    text = json.dumps(json_safe(data), indent=2, allow_nan=False) + "\n"
    if path == "-":
        sys.stdout.write(text)
        sys.stdout.flush()
    else:
        write_text(path, text, inputs=inputs)


def require_ros(command: str) -> None:
    if importlib.util.find_spec("rclpy") is None:
        raise InputError(f"{command} needs ROS 2's Python client (rclpy): pip install "
                         "'.[ros]' in this project, or source a ROS 2 Jazzy installation")


def tracking_flag(p: argparse.ArgumentParser) -> None:
    """Add ``--baseline-tracking off``, kept for scripts: ``on`` is refused."""
    p.add_argument("--baseline-tracking", choices=("off", "on"), default="off",
                   help="off (the only behaviour): the rest level is the calibration's or "
                   "the tare's; baseline tracking was removed, on is refused "
                   "(docs/results.md)")


def references_flag(p: argparse.ArgumentParser) -> None:
    p.add_argument("--references-every", type=float, metavar="SECONDS",
                   help="fuse the bag's own /NAME/strain_reference every SECONDS into the "
                   "output gain and offset, causally (a known strain now and then, as a robot "
                   "may have; scored on every sample; docs/results.md)")


def tare_flag(p: argparse.ArgumentParser) -> None:
    p.add_argument("--tare", choices=("calibration", "auto"), default="calibration",
                   help="rest resistance from the calibration (default) or from the run's "
                   "first seconds at rest (auto)")
