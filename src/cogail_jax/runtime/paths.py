"""Where a command writes what it makes: checked before the work starts, so that nothing is lost at its end."""
from __future__ import annotations

import os
from pathlib import Path


class OutputError(ValueError):
    """A path a command was told to write that it cannot; the message names it and what to do."""


def output_dir(path: str | os.PathLike, option: str, fix: str = "pass a folder you can write") -> Path:
    """``path`` as a folder to write in, made if missing; ``OutputError`` naming ``option`` and ending in ``fix``
    if it is a file, lies under a file, or cannot be made or written."""
    path = Path(path)
    if any(p.exists() and not p.is_dir() for p in (path, *path.parents)):
        raise OutputError(f"{option} {path} is a file or lies under one: {fix}")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputError(f"{option} {path}: cannot make the folder ({e.strerror}): {fix}") from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise OutputError(f"{option} {path}: cannot write in it: {fix}")
    return path


def output_file(path: str | os.PathLike, option: str, example: str) -> Path:
    """``path`` as a file to write, its folder made if missing; ``OutputError`` naming ``option`` if it is a folder,
    or its folder is a file, lies under one or cannot be made or written. ``example``: a file name to suggest."""
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{option} {path} is a folder: pass a file name, e.g. {path / example}")
    output_dir(path.parent, f"{option} {path}: its folder", "pass a path you can write")
    return path
