"""numba set-up: a writable cache directory, then the ``njit`` every kernel uses.

numba's ``cache=True`` writes next to the source file; on a read-only install (a ROS 2
``install/`` tree, a system site-packages) that fails at import. If ``NUMBA_CACHE_DIR``
is not set and the package directory is not writable, point it at a per-user cache
directory before numba is imported. Every module imports numba through this one.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path


def _writable(path: Path) -> bool:
    return os.access(path, os.W_OK)


def _choose_cache_dir() -> str | None:
    if os.environ.get("NUMBA_CACHE_DIR"):
        return None
    pycache = Path(__file__).resolve().parent
    if _writable(pycache):
        return None
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    for candidate in (Path(base) / "strain_comp" / "numba",
                      Path(tempfile.gettempdir()) / f"strain_comp-numba-{os.getuid()}"):
        try:
            candidate.mkdir(parents=True, exist_ok=True)
        except OSError:
            continue
        if _writable(candidate):
            return str(candidate)
    return None


_cache_dir = _choose_cache_dir()
if _cache_dir is not None:
    os.environ["NUMBA_CACHE_DIR"] = _cache_dir

import numba  # noqa: E402

if _cache_dir is not None:  # numba already imported elsewhere: its config was read before
    numba.config.CACHE_DIR = _cache_dir


def njit(*args: object, **options: object) -> object:
    """``numba.njit`` with ``cache=True`` and ``nogil=True`` unless told otherwise.

    Use as ``@njit`` or ``@njit(fastmath=True)``.
    """
    options.setdefault("cache", True)
    options.setdefault("nogil", True)
    return numba.njit(*args, **options)

__all__ = ["njit", "numba"]
