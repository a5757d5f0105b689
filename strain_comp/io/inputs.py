"""Input paths checked before anything opens them: one line naming the path otherwise."""

from __future__ import annotations

import os
import stat

from strain_comp.errors import InputError


def existing(path: str | os.PathLike[str], what: str, *, directory: bool = False) -> str:
    """Check an input path before anything opens it (a FIFO would block a reader).

    Args:
        path: The input path.
        what: What the path holds, for the message (``"bag"``, ``"calibration"``, ...).
        directory: A directory is accepted too (a rosbag2 bag).

    Returns:
        ``path`` as a string.

    Raises:
        InputError: The path is missing, unreadable, or not a regular file (nor, with
            ``directory``, a directory), naming it.

    """
    path = os.fspath(path)
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise InputError(f"{path}: {what} not found") from None
    except OSError as err:
        raise InputError(f"{path}: {what} cannot be read ({err.strerror})") from None
    if not (stat.S_ISREG(mode) or (directory and stat.S_ISDIR(mode))):
        kind = "a directory" if stat.S_ISDIR(mode) else "not a regular file"
        raise InputError(f"{path}: {what} is {kind}")
    return path
