"""Columns for rerun's ``send_columns`` (rerun-sdk 0.41), built straight from numpy buffers: the time index and
``Scalars`` of a chunk of samples, as :class:`gantry_twin.telemetry.observer.RerunObserver` sends them."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import rerun as rr

from gantry_twin.telemetry.dashboard import TIMELINE


class TimeIndex:
    """A ``sim_time`` column (rerun's TimeColumnLike) in whole nanoseconds, rounded rather than truncated.

    Built straight from the int64 buffer: ``rr.TimeColumn`` does the same through slower conversions.
    """

    def __init__(self, t_s: np.ndarray) -> None:
        self._times = pa.array(np.rint(np.asarray(t_s, dtype=float) * 1e9).astype(np.int64)).view(pa.duration("ns"))

    def timeline_name(self) -> str:
        return TIMELINE

    def as_arrow_array(self) -> pa.Array:
        return self._times


class ArrowBatch:
    """A ready pyarrow array as a rerun ComponentBatchLike."""

    def __init__(self, array: pa.Array) -> None:
        self._array = array

    def as_arrow_array(self) -> pa.Array:
        return self._array


SCALARS = rr.Scalars.descriptor_scalars()


def scalar_column(values: np.ndarray) -> rr.ComponentColumn:
    """``Scalars`` column of N rows of k values from an (N,) or (N, k) array (= ``rr.Scalars.columns``, faster)."""
    values = np.asarray(values, dtype=np.float64)
    rows = values.shape[0]
    width = 1 if values.ndim == 1 else int(np.prod(values.shape[1:]))
    offsets = np.arange(0, rows * width + 1, width, dtype=np.int32)
    return rr.ComponentColumn(SCALARS, ArrowBatch(pa.array(values.reshape(-1))), offsets=offsets)
