"""numba set-up, through which every module imports numba: on a read-only install (a ROS 2
``install/`` tree) ``cache=True`` would fail at import, so unless ``NUMBA_CACHE_DIR`` is set
a per-user cache directory is chosen first; then the ``njit`` every kernel uses."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path
from types import FunctionType
from typing import TYPE_CHECKING, Any, TypeVar, overload

if TYPE_CHECKING:
    from numba.core.dispatcher import Dispatcher


def _choose_cache_dir() -> str | None:
    if os.environ.get("NUMBA_CACHE_DIR"):
        return None
    pycache = Path(__file__).resolve().parent
    if os.access(pycache, os.W_OK):
        return None
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    for candidate in (Path(base) / "strain_comp" / "numba",
                      Path(tempfile.gettempdir()) / f"strain_comp-numba-{os.getuid()}"):
        try:
            candidate.mkdir(parents=True, exist_ok=True)
        except OSError:
            continue
        if os.access(candidate, os.W_OK):
            return str(candidate)
    return None


_cache_dir = _choose_cache_dir()
if _cache_dir is not None:
    os.environ["NUMBA_CACHE_DIR"] = _cache_dir

import numba  # noqa: E402

if _cache_dir is not None:  # numba already imported elsewhere: its config was read before
    numba.config.CACHE_DIR = _cache_dir  # type: ignore[attr-defined]  # set at runtime

_F = TypeVar("_F", bound=Callable[..., Any])


@overload
def njit(function: _F, /) -> Dispatcher[_F]: ...
@overload
def njit(function: None = None, /, **options: Any) -> Callable[[_F], Dispatcher[_F]]: ...


def njit(function: _F | None = None, /,
         **options: Any) -> Dispatcher[_F] | Callable[[_F], Dispatcher[_F]]:
    """``numba.njit`` with ``cache=True`` and ``nogil=True`` unless told otherwise."""
    options.setdefault("cache", True)
    options.setdefault("nogil", True)

    def compile_(python_function: _F) -> Dispatcher[_F]:
        dispatcher: Dispatcher[_F] = numba.njit(python_function, **options)
        return dispatcher

    return compile_ if function is None else compile_(function)


_SPECIALISED: set[str] = set()


def specialise(template: Callable[..., Any], bound: Mapping[str, Dispatcher[Any]],
               **options: Any) -> Dispatcher[Any]:
    """``template`` compiled (``njit``) with its global names ``bound`` to these kernels."""
    name = "__".join([template.__name__, *(
        f"{key}_{kernel.py_func.__module__.replace('.', '_')}_{kernel.py_func.__name__}"
        for key, kernel in sorted(bound.items()))])
    if name in _SPECIALISED:
        raise ValueError(f"{name} is specialised already")
    _SPECIALISED.add(name)
    function = FunctionType(template.__code__, {**template.__globals__, **bound}, name,
                            template.__defaults__)
    function.__qualname__ = name
    function.__doc__ = template.__doc__
    options.setdefault("_nrt", False)
    return njit(function, **options)

__all__ = ["njit", "numba", "specialise"]
