"""numba's cache goes somewhere writable when the package directory is read-only.

The package is copied to a directory that is made truly read-only: a read-only bind mount
in a private mount namespace when running as root (root ignores file modes), file modes
otherwise. A kernel is then compiled with ``cache=True`` in a fresh interpreter.
"""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import pytest

import strain_comp

PACKAGE_DIR = Path(strain_comp.__file__).resolve().parent
PROBE = ("from strain_comp._numba import njit\n\n"
         "@njit\n"
         "def f(x):\n    return x + 1.0\n")
KERNEL = ("import os, probe_kernel\n"
          "assert probe_kernel.f(1.0) == 2.0\n"
          "print(os.environ['NUMBA_CACHE_DIR'])")


def _read_only_command(site: Path) -> list[str]:
    python = [sys.executable, "-c", KERNEL]
    if os.geteuid() != 0:
        for path in [site, *site.rglob("*")]:
            path.chmod(path.stat().st_mode & ~(stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH))
        return python
    if shutil.which("unshare") is None:
        pytest.skip("running as root without unshare: cannot make a read-only directory")
    script = ('mount --bind "$0" "$0" && mount -o remount,bind,ro "$0" && '
              'touch "$0/probe" 2>/dev/null && exit 97; exec "$@"')
    return ["unshare", "-m", "sh", "-c", script, str(site), *python]


@pytest.mark.parametrize("home_writable", [True, False])
def test_read_only_install_imports_and_compiles(tmp_path: Path, home_writable: bool) -> None:
    """Plain numba raises 'cannot cache function' here when HOME is read-only too."""
    site = tmp_path / "site"
    shutil.copytree(PACKAGE_DIR, site / "strain_comp",
                    ignore=shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc"))
    (site / "probe_kernel.py").write_text(PROBE)  # a kernel living in the read-only tree
    home = tmp_path / "home" if home_writable else site / "home"
    home.mkdir()
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "XDG_CACHE_HOME")}
    env.update(PYTHONPATH=str(site), HOME=str(home), TMPDIR=str(scratch),
               PYTHONDONTWRITEBYTECODE="1")
    try:
        done = subprocess.run(_read_only_command(site), env=env, capture_output=True,
                              text=True, timeout=120, cwd=tmp_path)
    finally:
        for path in [site, *site.rglob("*")]:
            path.chmod(path.stat().st_mode | stat.S_IWUSR)
    if done.returncode == 97:
        pytest.fail("the directory was still writable: the test set-up did not work")
    if done.returncode != 0 and "mount" in done.stderr and "strain_comp" not in done.stderr:
        pytest.skip(f"no read-only bind mount here: {done.stderr.strip()}")
    assert done.returncode == 0, done.stderr
    cache_dir = Path(done.stdout.strip())
    assert cache_dir.is_relative_to(home if home_writable else scratch)
    assert any(cache_dir.rglob("*.nbi")), "the kernel was not cached in the fallback directory"
    assert not any(site.rglob("*.nbi"))
