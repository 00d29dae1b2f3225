"""Command-line value types shared by the commands: each refuses a bad value in one sentence (argparse prints it
after the usage line)."""
from __future__ import annotations

import argparse

from ..runtime.paths import OutputError, output_dir, output_file


def positive(text: str) -> int:
    """A positive integer; 1e6 is read as 1000000, 2.5 is refused."""
    try:
        x = float(text)
        v = int(x)
    except (ValueError, OverflowError):
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if v <= 0 or x != v:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return v


def positive_list(text: str) -> tuple[int, ...]:
    """Comma-separated positive integers, at least one."""
    items = [s for s in text.split(",") if s.strip()]
    if not items:
        raise argparse.ArgumentTypeError(f"expected comma-separated positive integers, e.g. 64,1024, got {text!r}")
    try:
        return tuple(positive(s.strip()) for s in items)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated positive integers, e.g. 64,1024, got {text!r}") from None


def seed(text: str) -> int:
    """A seed: an integer JAX's 32-bit keys hold without two seeds meaning one key."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer seed, got {text!r}") from None
    if not 0 <= v < 2 ** 32:
        raise argparse.ArgumentTypeError(f"a seed is an integer from 0 to {2 ** 32 - 1}, got {text}")
    return v


def seeds(text: str) -> tuple[int, ...]:
    """Comma-separated seeds, at least one."""
    try:
        values = tuple(int(s) for s in text.split(",") if s.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--seeds must be comma-separated integers, e.g. 300,400,500, got {text!r}") from None
    if not values:
        raise argparse.ArgumentTypeError("--seeds needs at least one integer")
    for v in values:
        seed(str(v))
    return values


def file_out(example: str):
    """An argparse ``type``: a file to write, checked at once (``runtime.paths.output_file``); ``example`` is the file
    name suggested for a folder, e.g. ``type=file_out("results.json")``."""
    def check(text: str) -> str:
        try:
            return str(output_file(text, "", example))
        except OutputError as e:
            raise argparse.ArgumentTypeError(str(e)) from None

    return check


def folder_out(text: str) -> str:
    """An argparse ``type``: a folder to write in, checked at once (``runtime.paths.output_dir``)."""
    try:
        return str(output_dir(text, ""))
    except OutputError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
