"""Where a command writes what it makes: checked before the work starts, so that nothing is lost at its end. The
checks make nothing: the folders a path needs are made when it is written."""
from __future__ import annotations

import os
from pathlib import Path


class OutputError(ValueError):
    """A path a command was told to write that it cannot; the message names it and what to do."""


def _writable_from(path: Path, option: str, fix: str) -> None:
    """``OutputError`` unless the nearest existing folder at or above ``path`` is a folder this process can write."""
    there, name = path.absolute(), f"{option} {path}".strip()
    while not there.exists():
        there = there.parent
    if not there.is_dir():
        raise OutputError(f"{name} {'is' if there == path.absolute() else f'lies under {there},'} a file: {fix}")
    if not os.access(there, os.W_OK | os.X_OK):
        raise OutputError(f"{name}: cannot write in {there}: {fix}")


def output_dir(path: str | os.PathLike, option: str, fix: str = "pass a folder you can write") -> Path:
    """``path`` as a folder to write in (made when written); ``OutputError`` naming ``option`` and ending in
    ``fix`` if it is a file, lies under one, or cannot be written."""
    path = Path(path)
    _writable_from(path, option, fix)
    return path


def output_file(path: str | os.PathLike, option: str, example: str, keep: bool = False) -> Path:
    """``path`` as a file to write (its folders made when written); a file already there is replaced, or, with
    ``keep`` (a file the user made, e.g. a dataset), refused. ``OutputError`` naming ``option`` if it is a folder,
    lies under a file, cannot be written (nor its folder), or exists and ``keep``. ``example``: a file name to
    suggest in a folder."""
    path = Path(path)
    name = f"{option} {path}".strip()
    if path.is_dir():
        raise OutputError(f"{name} is a folder: pass a file name, e.g. {path / example}")
    if path.exists() or path.is_symlink():
        if keep:
            raise OutputError(f"{name} exists: remove it or pass another file name")
        if not os.access(path, os.W_OK):
            raise OutputError(f"{name} exists and cannot be written: make it writable or pass another file name")
        if not os.access(folder := path.absolute().parent, os.W_OK | os.X_OK):
            raise OutputError(f"{name}: cannot write in {folder}: pass a path you can write")
        return path
    _writable_from(path, option, "pass a path you can write")
    return path
