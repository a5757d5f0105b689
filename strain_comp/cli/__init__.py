"""The ``strain-comp`` command line (docs/design.md, "Command line"): the parser assembled
from one module per command (``cli.common.Command``), each importing its machinery only when
it runs, so ``--help`` and ``--version`` stay fast."""

from __future__ import annotations

import argparse
import os
import signal
import sys
import tempfile
import textwrap
import threading
import traceback
from collections.abc import Sequence

from strain_comp.cli import (
    diagnose,
    evaluate,
    fit,
    import_csv,
    node,
    play,
    recalibrate,
    replay,
    simulate,
    start,
)
from strain_comp.cli.common import PROG, Command, Parser, UsageError, err
from strain_comp.errors import StrainCompError, Terminated, raise_terminated
from strain_comp.version import __version__

COMMANDS: tuple[Command, ...] = (simulate, import_csv, fit, start, evaluate, replay, diagnose,
                                 recalibrate, node, play)
"""Every command, in the order ``strain-comp --help`` lists them."""
EXIT_USER = 2
"""Bad input, refused output or a usage error: one line ``strain-comp: error: ...``."""
EXIT_BUG = 70
"""A fault of strain_comp itself (EX_SOFTWARE of sysexits.h)."""
EXIT_INTERRUPTED = 130
EXIT_TERMINATED = 143


def build_parser() -> argparse.ArgumentParser:
    """The argument parser; subcommand names and flags as docs/design.md fixes them."""
    parser = Parser(
        prog=PROG, formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Calibrated strain from soft resistive strain sensors: "
        "simulate or import data, fit, evaluate, replay, diagnose, run.",
        epilog="example:\n  strain-comp evaluate bags/demo_rates.mcap --calibration "
        "config/demo_calibration.yaml\n\n'strain-comp COMMAND --help' describes a command.")
    parser.add_argument("--version", action="version", version=f"{PROG} {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for command in COMMANDS:
        p = sub.add_parser(command.NAME, help=command.SUMMARY,
                           description=textwrap.fill(command.DESCRIPTION, 88),
                           epilog="example:\n  " + command.EXAMPLE,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        command.add_arguments(p)
        p.set_defaults(func=command.run)
        p.add_argument("-q", "--quiet", action="store_true",
                       help="no notes on stderr (what was written, tares, skipped data); "
                       "results and errors still print")
        p.add_argument("--debug", action="store_true",
                       help="on a fault of strain-comp itself, print the traceback instead "
                       "of writing it to a file")
    return parser


def internal_error(error: BaseException, debug: bool) -> int:
    """A fault of the program: one line naming the file with the traceback (``--debug``: it)."""
    text = "".join(traceback.format_exception(error))
    what = " ".join(f"{type(error).__name__}: {error}".split())
    if debug:
        sys.stderr.write(text)
        where = "the traceback is above"
    else:
        try:
            fd, path = tempfile.mkstemp(prefix="strain-comp-", suffix=".log")
            with os.fdopen(fd, "w", encoding="utf-8") as log:
                log.write(f"{PROG} {__version__}\n{text}")
            where = f"the traceback is in {path}"
        except OSError as failed:
            where = f"the traceback could not be written ({failed}); rerun with --debug"
    err(f"{PROG}: internal error: {what} (a bug: {where}; please report it)")
    return EXIT_BUG


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code (0, 2, 70, 130 or 143: docs/design.md)."""
    handler = signal.getsignal(signal.SIGTERM)
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, raise_terminated)
    try:
        return _main(argv)
    except Terminated:
        return EXIT_TERMINATED
    finally:
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, signal.SIG_DFL if handler is None else handler)


def _main(argv: Sequence[str] | None) -> int:
    """``main`` under its SIGTERM handler."""
    debug = False
    try:
        parser = build_parser()
        try:
            args, extra = parser.parse_known_args(argv)
        except SystemExit:  # --help, --version or --list printed; nothing else exits
            return 0
        debug = bool(args.debug)
        if extra:
            raise UsageError(f"{args.command}: unrecognized arguments: {' '.join(extra)} "
                             f"(see {PROG} {args.command} --help)")
        import numpy as np

        # overflow on hostile data gives inf / NaN, which the commands screen where it
        # matters; numpy's warning lines would break the one-line contract
        with np.errstate(all="ignore"):
            return int(args.func(args))
    except StrainCompError as error:
        message = str(error)
    except BrokenPipeError:  # the reader of stdout went away (e.g. `| head`)
        sys.stdout = open(os.devnull, "w")  # no second error when Python flushes at exit
        message = "stdout closed before the output was complete (broken pipe)"
    except OSError as error:  # a file the user named cannot be read or written
        where = error.filename if error.filename is not None else ""
        message = f"{where}: {error.strerror or error}" if where else str(error)
    except KeyboardInterrupt:
        err(f"{PROG}: interrupted")
        return EXIT_INTERRUPTED
    except SystemExit as error:  # a library asked to exit: still one line
        message = f"unexpected SystemExit: {error}"
    except Exception as error:  # a fault of strain_comp, said as such
        return internal_error(error, debug)
    err(f"{PROG}: error: " + " ".join(message.split()))
    return EXIT_USER
