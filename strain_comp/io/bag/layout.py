"""A bag's storage files: a bare ``.mcap`` or ``.db3``, or a rosbag2 directory read through
its ``metadata.yaml`` (docs/reliability.md, "Bags")."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from strain_comp.errors import BagError
from strain_comp.io.bag.db3 import DECOMPRESS_HINT, refuse_compressed_file
from strain_comp.io.safe_yaml import LimitError, load_limited

MAX_METADATA_BYTES = 2**20
"""rosbag2 metadata.yaml larger than this is refused (a real one is a few kB)."""
MAX_STORAGE_FILES = 4096
"""Storage files of one bag directory (each counted once): more is refused."""


def _inside(path: Path, file: Path) -> bool:
    """``file`` is a regular file that resolves (symbolic links followed) into ``path``."""
    try:
        return file.resolve().is_relative_to(path.resolve()) and file.is_file()
    except (OSError, RuntimeError):  # a symbolic link loop
        return False


def _metadata(meta: Path) -> dict[str, Any]:
    """``rosbag2_bagfile_information`` of a metadata.yaml, within ``MAX_METADATA_BYTES``."""
    try:
        with meta.open("rb") as handle:
            data = handle.read(MAX_METADATA_BYTES + 1)
        if len(data) > MAX_METADATA_BYTES:
            raise BagError(f"{meta}: rosbag2 metadata larger than {MAX_METADATA_BYTES} bytes")
        info = load_limited(data.decode("utf-8")) or {}
    except (OSError, UnicodeDecodeError, yaml.YAMLError, LimitError) as exc:
        detail = " ".join(str(exc).split())
        raise BagError(f"{meta}: unreadable rosbag2 metadata ({detail})") from None
    where = "rosbag2_bagfile_information"
    if not isinstance(info, dict) or not isinstance(info.get(where, {}), dict):
        raise BagError(f"{meta}: {where} must be a mapping")
    bagfile: dict[str, Any] = info.get(where, {})
    return bagfile


def _metadata_files(path: Path, meta: Path, info: dict[str, Any]) -> list[Path]:
    """The files metadata.yaml lists that exist, each once, all inside ``path``."""
    rel = info.get("relative_file_paths", [])
    if not isinstance(rel, list) or not all(isinstance(p, str) for p in rel):
        raise BagError(f"{meta}: rosbag2_bagfile_information.relative_file_paths must be a "
                       "list of strings")
    rel = list(dict.fromkeys(rel))
    _bounded(meta, rel)
    for p in rel:
        if Path(p).is_absolute() or ".." in Path(p).parts:
            raise BagError(f"{meta}: relative_file_paths: {p!r} leaves the bag directory")
    files = [path / p for p in rel if (path / p).exists()]
    for file in files:
        if not _inside(path, file):
            raise BagError(f"{meta}: relative_file_paths: {file.name!r} is not a regular "
                           "file inside the bag directory")
    unique: dict[Path, Path] = {}
    for file in files:
        unique.setdefault(file.resolve(), file)
    return list(unique.values())


def _bounded(where: Path, files: list[str] | list[Path]) -> None:
    """BagError for more than ``MAX_STORAGE_FILES`` storage files."""
    if len(files) > MAX_STORAGE_FILES:
        raise BagError(f"{where}: {len(files)} storage files, at most {MAX_STORAGE_FILES} "
                       "are read")


def bag_storage(path: Path) -> tuple[list[Path], bool]:
    """A bag's storage files, checked before any is opened; are messages zstd one by one?"""
    if not path.exists():
        raise BagError(f"{path}: no such bag")
    if not (path.is_dir() or path.is_file()):
        raise BagError(f"{path}: not a regular file or a rosbag2 directory")
    if path.is_file():
        if path.suffix == ".zstd":
            refuse_compressed_file(path)
        return [path], False
    meta = path / "metadata.yaml"
    info = _metadata(meta) if _inside(path, meta) else {}
    files = _metadata_files(path, meta, info)
    if not files:
        files = [f for pattern in ("*.mcap", "*.db3", "*.mcap.zstd", "*.db3.zstd")
                 for f in sorted(path.glob(pattern)) if _inside(path, f)]
        _bounded(path, files)
    if not files:
        raise BagError(f"{path}: directory holds no .mcap or .db3 file")
    for file in files:
        if file.suffix == ".zstd":
            refuse_compressed_file(file)
    return files, _per_message_zstd(meta, info, files)


def _per_message_zstd(meta: Path, info: dict[str, Any], files: list[Path]) -> bool:
    """Are the messages zstd-compressed one by one? BagError for any other compression."""
    mode = str(info.get("compression_mode") or "").lower()
    if mode in ("", "none"):
        return False
    kind = str(info.get("compression_format") or "")
    if mode != "message" or kind != "zstd" or any(f.suffix != ".db3" for f in files):
        raise BagError(f"{meta}: compression {kind or '?'} per {mode} is not read here; "
                       + DECOMPRESS_HINT)
    return True
