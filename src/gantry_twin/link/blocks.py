"""Sample blocks: every 0.2 ms sample of a run, N at a time, as one flat array of doubles (docs/live-link.md).

A block is what ``gantry-twin serve`` publishes about 50 times a second and what ``monitor --opcua`` reads:

    [first_index, first_time_s, samples, signals, v(0, 0), v(1, 0), ..., v(samples - 1, signals - 1)]

the header (:data:`HEADER`), then the samples signal by signal (column-major: the N values of the first signal of
:data:`SIGNALS`, then the next). ``first_index`` counts the server's samples from 0 and runs on across the
passes of ``serve --loop``, so that a subscriber tells a gap by it. Each value is the number the run's
trace.parquet stores (:func:`gantry_twin.outputs.tracefile.trace_table`: float32 where the file is float32), so
that a stream and the recorded trace are the same numbers and give the same estimates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gantry_twin.loop.trace import Trace
from gantry_twin.outputs.tracefile import TRACE_COLUMNS, stored_dtype
from gantry_twin.theta import THETA_NAMES, THETA_UNITS

#: The header's fields, in order.
HEADER: tuple[str, ...] = ("first_index", "first_time_s", "samples", "signals")
#: The signals of a block, in order, with their units. The measured positions are the encoder's (what a
#: machine's control reads), the true ones the plant's; theta_hat is the controller's estimate (NaN for a
#: controller without one), volt units (docs/equations.md).
SIGNALS: tuple[tuple[str, str], ...] = (
    ("t_s", "s"),
    ("x_meas_m", "m"),
    ("y_meas_m", "m"),
    ("x_m", "m"),
    ("y_m", "m"),
    ("x_d_m", "m"),
    ("y_d_m", "m"),
    ("u_x_v", "V"),
    ("u_y_v", "V"),
    ("eps_c_m", "m"),
    *((f"theta_hat_{name}", unit) for name, unit in zip(THETA_NAMES, THETA_UNITS, strict=True)),
)
SIGNAL_NAMES: tuple[str, ...] = tuple(name for name, _ in SIGNALS)
#: The most samples a block may declare (a client reading blocks refuses a larger one before allocating it).
MAX_BLOCK_SAMPLES = 100_000


class BlockError(ValueError):
    """A block that cannot be read; the message is one line."""


@dataclass(frozen=True)
class Block:
    """Samples [first_index, first_index + n) of a run: ``values`` (n, len(SIGNALS)), float64."""

    first_index: int
    first_time_s: float
    values: np.ndarray

    @property
    def samples(self) -> int:
        return int(self.values.shape[0])

    @property
    def end_index(self) -> int:
        return self.first_index + self.samples

    def encode(self) -> list[float]:
        """The flat array a server publishes (module docstring)."""
        n, m = self.values.shape
        head = np.array([self.first_index, self.first_time_s, n, m], dtype=np.float64)
        return np.concatenate([head, self.values.T.ravel()]).tolist()


def decode(flat: object, signals: int = len(SIGNALS)) -> Block | None:
    """A published array back into a :class:`Block` (None for the empty array a server holds before its first
    block); :class:`BlockError` if it is not one of ``signals`` signals."""
    values = np.asarray(flat if flat is not None else [], dtype=np.float64)
    if values.size == 0:
        return None
    if values.ndim != 1 or values.size < len(HEADER):
        raise BlockError(f"a block is a flat array of at least {len(HEADER)} doubles, got shape {values.shape}")
    first, t0, n, m = values[: len(HEADER)]
    if not all(np.isfinite((first, t0, n, m))) or first < 0 or first != int(first):
        raise BlockError(f"a block's header {values[:4].tolist()} is not [first_index >= 0, time, samples, signals]")
    if m != signals or not 0 < n <= MAX_BLOCK_SAMPLES or n != int(n) or values.size != len(HEADER) + int(n) * signals:
        raise BlockError(
            f"a block of {n:g} samples x {m:g} signals in {values.size - len(HEADER)} values; "
            f"expected {signals} signals and 1-{MAX_BLOCK_SAMPLES} samples"
        )
    return Block(int(first), float(t0), values[len(HEADER) :].reshape(int(m), int(n)).T.copy())


def trace_values(trace: Trace, start: int, stop: int) -> np.ndarray:
    """Samples [start, stop) of a run's trace as (n, len(SIGNALS)) float64, each value as trace.parquet stores it
    (:func:`gantry_twin.outputs.tracefile.stored_dtype`; NaN for a signal the run does not have)."""
    rows = trace.rows(start, stop)
    values = np.full((stop - start, len(SIGNALS)), np.nan)
    theta = trace.controller_state.get("theta_hat")
    for j, name in enumerate(SIGNAL_NAMES):
        if name in TRACE_COLUMNS:
            attribute, column = TRACE_COLUMNS[name]
            series = getattr(trace, attribute)[rows]
            values[:, j] = (series if column is None else series[:, column]).astype(stored_dtype(name))
        elif theta is not None:  # theta_hat_<name>: the controller's logged estimate
            values[:, j] = theta[rows][:, THETA_NAMES.index(name.removeprefix("theta_hat_"))].astype(stored_dtype(name))
    return values
