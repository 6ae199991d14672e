"""A stop signal that lands in a C callback (numba's compile calls back into Python through ctypes) is not lost:
the callback can only drop the exception, so stop_signals_interrupt keeps it and the run's SwallowedInterrupt
observer raises it at the next chunk (seen: SIGHUP during a compile printed a traceback and the run went on)."""

from __future__ import annotations

import ctypes
import signal

import pytest

from gantry_twin.outputs.signals import Interrupted, SwallowedInterrupt, stop_signals_interrupt


def _callback_that_raises(signum: int):
    @ctypes.CFUNCTYPE(None)
    def callback() -> None:
        raise Interrupted(signum)

    return callback


def test_an_interrupt_dropped_by_a_c_callback_is_raised_at_the_next_chunk(capsys):
    with stop_signals_interrupt():
        _callback_that_raises(signal.SIGHUP)()  # C drops it: no exception here
        with pytest.raises(Interrupted) as caught:
            SwallowedInterrupt().on_chunk(None, 0, 1)
    assert caught.value.signum == signal.SIGHUP
    assert "Traceback" not in capsys.readouterr().err


def test_nothing_is_kept_outside_the_block():
    with stop_signals_interrupt():
        pass
    SwallowedInterrupt().on_chunk(None, 0, 1)  # nothing pending: no exception
