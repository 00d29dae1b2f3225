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
    if path.exists() and not path.is_dir() or any(p.exists() and not p.is_dir() for p in path.parents):
        raise OutputError(f"{option} {path} is not a folder (it is, or lies under, a file): {fix}")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputError(f"{option} {path}: cannot make the folder ({e.strerror}): {fix}") from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise OutputError(f"{option} {path}: cannot write in it: {fix}")
    return path


def output_file(path: str | os.PathLike, option: str, example: str) -> Path:
    """``path`` as a file to write, its folder made if missing; ``OutputError`` naming ``option`` if it is a folder,
    or its folder lies under a file or cannot be made or written. ``example``: a file name to suggest in a folder."""
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{option} {path} is a folder: pass a file name, e.g. {path / example}")
    parent = path.parent
    if parent.exists() and not parent.is_dir() or any(p.exists() and not p.is_dir() for p in parent.parents):
        raise OutputError(f"{option} {path} lies under a file, not a folder: pass a path you can write")
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputError(f"{option} {path}: cannot make its folder ({e.strerror}): pass a path you can write") from None
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputError(f"{option} {path}: cannot write in {parent}: pass a path you can write")
    return path
