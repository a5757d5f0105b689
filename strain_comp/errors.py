"""The one errors module of strain_comp: the command line turns every ``StrainCompError``
into exit code 2 and one line on stderr."""

from __future__ import annotations


class StrainCompError(Exception):
    """Base class of every error strain_comp raises on bad input."""


class CalibrationError(StrainCompError):
    """A calibration file is missing, malformed or out of range."""

    def __init__(self, path: str, field: str, problem: str) -> None:
        self.path = path
        self.field = field
        self.problem = problem
        super().__init__(f"{path}: {field}: {problem}")


class BagError(StrainCompError):
    """A bag cannot be read or written, or lacks a topic that is required."""


class FitError(StrainCompError):
    """A model cannot be fitted to the data given (too few samples, no excitation, ...)."""


class InputError(StrainCompError):
    """A command-line argument or an input file other than a bag or calibration is bad."""


class ParameterError(StrainCompError):
    """A model or setting parameter is missing or out of range."""

    def __init__(self, field: str, problem: str) -> None:
        self.field = field
        self.problem = problem
        super().__init__(f"{field}: {problem}")


class OutputError(StrainCompError):
    """An output path cannot be written: it is an input, or not a regular file."""


class Terminated(BaseException):
    """SIGTERM arrived: a command unwinds as on Ctrl-C, ``with`` blocks cleaning up (exit 143)."""


def raise_terminated(signum: int, frame: object) -> None:
    """A SIGTERM handler: raise ``Terminated`` where the main thread is."""
    raise Terminated
