"""The one way strain_comp writes a file: atomically (a temporary file beside it, fsynced,
renamed), never over an input or a non-file (docs/reliability.md)."""

from __future__ import annotations

import os
import stat
import tempfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import BinaryIO

from strain_comp.errors import OutputError

PathLike = str | os.PathLike[str]


def check_output(path: PathLike, inputs: Iterable[PathLike] = ()) -> Path:
    """Check that ``path`` may be written by a command reading ``inputs``."""
    target = Path(path)
    try:
        info = target.lstat()
    except FileNotFoundError:
        info = None
    except OSError as err:
        raise OutputError(f"{target}: cannot check the output path: {err.strerror}") from None
    if info is not None and not stat.S_ISREG(info.st_mode):
        kind = "a symbolic link" if stat.S_ISLNK(info.st_mode) else "not a regular file"
        raise OutputError(f"{target}: refusing to replace it ({kind})")
    for source in inputs:
        if info is not None and _same_file(target, Path(source)):
            raise OutputError(f"{target}: the output is the input {source}; choose another path")
        if info is not None and Path(source).is_dir() and _same_file(target.parent, Path(source)):
            raise OutputError(f"{target}: the output is inside the input bag directory {source}; "
                              "choose another path")
    return target


def check_distinct(outputs: Iterable[PathLike | None]) -> None:
    """Check that no two of one command's outputs are one path or one existing file."""
    seen: list[Path] = []
    for out in outputs:
        if out is None:
            continue
        path = Path(out)
        for other in seen:
            if os.path.realpath(path) == os.path.realpath(other) or _same_file(path, other):
                raise OutputError(f"{path}: given for two outputs ({other} too); each output "
                                  "needs its own path")
        seen.append(path)


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _file_mode(path: Path) -> int:
    """The mode the file would get if written in place: the old file's, else 0o666 & ~umask."""
    try:
        return path.stat().st_mode & 0o777
    except FileNotFoundError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


class AtomicFile:
    """A temporary file beside ``path`` that ``commit()`` renames over it, ``discard()`` deletes."""

    def __init__(self, path: PathLike, *, inputs: Iterable[PathLike] = ()) -> None:
        self.inputs = list(inputs)
        self.path = check_output(path, self.inputs)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".tmp",
                                       dir=self.path.parent)
        except OSError as err:
            raise OutputError(f"{self.path}: cannot write: {err.strerror or err}") from None
        self.tmp = Path(tmp)
        self.handle: BinaryIO = os.fdopen(fd, "wb")
        self.done = False

    @contextmanager
    def discarded_on_error(self) -> Iterator[None]:
        """Discard on any error; an OSError raised as ``OutputError`` naming the target."""
        try:
            yield
        except OSError as err:
            self.discard()
            raise OutputError(f"{self.path}: cannot write: {err.strerror or err}") from None
        except BaseException:
            self.discard()
            raise

    def commit(self) -> None:
        """Flush, fsync, rename over the target and fsync the directory (once)."""
        if self.done:
            return
        with self.discarded_on_error():
            with self.handle:
                self.handle.flush()
                os.fchmod(self.handle.fileno(), _file_mode(self.path))
                os.fsync(self.handle.fileno())
            check_output(self.path, self.inputs)
            os.replace(self.tmp, self.path)
            self.done = True
            directory = os.open(self.path.parent, os.O_RDONLY)  # the rename made durable
            try:
                os.fsync(directory)
            finally:
                os.close(directory)

    def discard(self) -> None:
        """Close and delete the temporary file; the target is left as it was (once)."""
        if self.done:
            return
        self.done = True
        try:
            self.handle.close()  # flushes: fails again when the write failed
        except OSError:
            pass
        finally:
            self.tmp.unlink(missing_ok=True)


@contextmanager
def atomic_output(path: PathLike, *, inputs: Iterable[PathLike] = ()) -> Iterator[BinaryIO]:
    """A binary file that replaces ``path`` only once it is complete."""
    output = AtomicFile(path, inputs=inputs)
    with output.discarded_on_error():
        yield output.handle
    output.commit()


def write_text(path: PathLike, text: str, *, inputs: Iterable[PathLike] = ()) -> None:
    """``text`` UTF-8 encoded to ``path``, atomically (a lone surrogate as its escape)."""
    with atomic_output(path, inputs=inputs) as handle:
        handle.write(text.encode("utf-8", "backslashreplace"))
