"""The argument types and options several verbs share: each type checks its value as it is read,
so a bad one is argparse's one line (exit 2) before anything runs.
"""

from __future__ import annotations

import argparse
import math


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text}")
    return value


def non_negative_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer, 0 or more, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be an integer, 0 or more, got {text}")
    return value


def positive_float(text: str) -> float:
    """A finite number above zero (frames per second: 0 divides by zero, -1 writes a BVH
    whose frame time is negative)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text}")
    return value


def port_number(text: str) -> int:
    """A TCP port number, 1 to 65535."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if not 1 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"must be a port number from 1 to 65535, got {text}")
    return value


def body_part(text: str) -> tuple[str, str]:
    """``PART=TEXT`` of ``generate --part``."""
    part, separator, sentence = text.partition("=")
    if not separator or not part.strip() or not sentence.strip():
        raise argparse.ArgumentTypeError(f'expected PART=TEXT, e.g. upper="a person waves", got {text!r}')
    return part.strip(), sentence.strip()


def add_ray_address(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--ray-address", help="join a Ray cluster (default: a local Ray; also RAY_ADDRESS)")


def add_max_seconds(parser: argparse.ArgumentParser, what: str) -> None:
    parser.add_argument("--max-seconds", type=float, help=f"refuse, before sampling, {what} (default 60; 0 = no cap)")


def add_overwrite(parser: argparse.ArgumentParser, what: str) -> None:
    parser.add_argument(
        "--overwrite", action="store_true", help=f"replace {what} when it exists (default: refuse, in one line)"
    )


def escaped(text: str) -> str:
    return text.replace("%", "%%")  # argparse %-formats help texts
