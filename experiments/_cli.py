"""Command-line helpers shared by the entry points."""

from __future__ import annotations

import argparse
import sys
from typing import NoReturn


def fail(parser: argparse.ArgumentParser | None, message: str) -> NoReturn:
    """Reports bad input and exits with status 2 (argparse's convention), without a traceback."""
    if parser is not None:
        parser.error(message)
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(2)
