"""The progress bar of a run on stderr, and whether a command shows one (``--progress``)."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from gantry_twin.loop.trace import RunInfo, Trace


class ProgressBar:
    """A tqdm bar on stderr in simulated seconds (an Observer; reads nothing it could change).

    Shown only when ``enabled`` (by default: stderr is a terminal) and only
    once a run has lasted ``delay_s`` of wall time, so short runs stay quiet.
    """

    def __init__(self, enabled: bool, delay_s: float = 1.0) -> None:
        self.enabled = enabled
        self.delay_s = delay_s
        self._bar: Any = None

    def on_start(self, run: RunInfo, trace: Trace) -> None:
        if not self.enabled:
            return
        from tqdm import tqdm

        self._bar = tqdm(
            total=run.samples,
            unit="s",
            unit_scale=trace.sample_period_s,
            desc=f"{run.controller_name}",
            file=sys.stderr,
            delay=self.delay_s,
            leave=False,
            bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.2f}/{total:.2f} s simulated [{elapsed}<{remaining}]",
        )

    def on_chunk(self, trace: Trace, start: int, stop: int) -> None:
        if self._bar is not None:
            self._bar.update(stop - start)

    def on_end(self, trace: Trace) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None


def add_progress_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--progress",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="progress bar on stderr (default: when stderr is a terminal)",
    )


def progress_wanted(args: argparse.Namespace) -> bool:
    """--progress / --no-progress, else on when stderr is a terminal."""
    return sys.stderr.isatty() if args.progress is None else args.progress


def progress_bar(args: argparse.Namespace) -> ProgressBar:
    """The progress bar of a ``run``."""
    return ProgressBar(progress_wanted(args))
