"""Cost of recording a run to an .rrd file at the full 5 kHz.

Run: ``python benchmarks/bench_telemetry.py [--duration 10] [--repeat 1]``

Times a DIARC run (5 kg, paper circle) without telemetry and with a
:class:`RerunObserver` saving to a temporary .rrd, alternately, and prints
the wall-time ratio (target: at most 1.25) and the observer's own time per
sample (time spent inside on_chunk/on_end plus the final flush).

The observer's cost per sample depends on the loop's speed: it sends at most
every 0.2 s of wall time, so a fast loop gets large, cheap batches and a slow
loop one send per chunk. ``--emulate-us 26`` also replays a recorded trace
through the observer with a busy-wait of that many microseconds per sample in
place of the physics (the observer's cost on a loop of another speed), with
and without recording, and prints that ratio too.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from gantry_twin import Payload, Plant, TimingLaw, circle, create, simulate
from gantry_twin.telemetry import RerunObserver


class Timed:
    """Wraps an observer and adds up the wall time spent in its callbacks."""

    def __init__(self, inner: RerunObserver) -> None:
        self.inner = inner
        self.seconds = 0.0

    def _timed(self, method, *args) -> None:
        t0 = time.perf_counter()
        method(*args)
        self.seconds += time.perf_counter() - t0

    def on_start(self, run, trace) -> None:
        self._timed(self.inner.on_start, run, trace)

    def on_chunk(self, trace, start, stop) -> None:
        self._timed(self.inner.on_chunk, trace, start, stop)

    def on_end(self, trace) -> None:
        self._timed(self.inner.on_end, trace)


def one_run(duration_s: float, rrd: Path | None) -> tuple[float, float, int, int]:
    """(wall s, observer s, samples, file bytes) of one run."""
    plant, controller = Plant(Payload(5.0)), create("diarc")
    observers = []
    timed = None
    if rrd is not None:
        timed = Timed(RerunObserver.to_file(rrd))
        observers.append(timed)
    t0 = time.perf_counter()
    trace = simulate(plant, circle(), TimingLaw(2.0), controller, duration_s, observers=observers)
    if timed is not None:
        t1 = time.perf_counter()
        timed.inner.close()
        timed.seconds += time.perf_counter() - t1
    wall = time.perf_counter() - t0
    size = rrd.stat().st_size if rrd is not None else 0
    return wall, (timed.seconds if timed else 0.0), trace.t_s.size, size


def _busy(seconds: float) -> None:
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        pass


class _Grab:
    """Keeps the RunInfo of a run."""

    def on_start(self, run, trace) -> None:
        self.run = run

    def on_chunk(self, trace, start, stop) -> None:
        pass

    def on_end(self, trace) -> None:
        pass


def emulated(us_per_sample: float, run, trace, rrd: Path | None) -> float:
    """Wall time of replaying a recorded trace chunk by chunk, the physics replaced by a busy-wait."""
    n, chunk = trace.t_s.size, 500
    observer = RerunObserver.to_file(rrd) if rrd is not None else None
    t0 = time.perf_counter()
    if observer is not None:
        observer.on_start(run, trace)
    for start in range(0, n, chunk):
        stop = min(n, start + chunk)
        _busy((stop - start) * us_per_sample * 1e-6)
        trace.filled = stop
        if observer is not None:
            observer.on_chunk(trace, start, stop)
    if observer is not None:
        observer.on_end(trace)
        observer.close()
    return time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=10.0, help="simulated seconds (default 10)")
    parser.add_argument("--repeat", type=int, default=1, help="pairs of runs (default 1)")
    parser.add_argument(
        "--emulate-us", type=float, default=None, metavar="US", help="also emulate a loop of US us/sample"
    )
    args = parser.parse_args()
    one_run(0.05, None)  # warm up imports, numba, MuJoCo
    plain, recorded, observer = [], [], []
    with tempfile.TemporaryDirectory() as folder:
        for i in range(args.repeat):
            wall, _, n, _ = one_run(args.duration, None)
            plain.append(wall)
            wall, obs, n, size = one_run(args.duration, Path(folder) / f"run{i}.rrd")
            recorded.append(wall)
            observer.append(obs)
    best_plain, best_recorded = min(plain), min(recorded)
    obs = min(observer)
    print(f"DIARC, {args.duration:g} s simulated, {n} samples, best of {args.repeat}")
    print(f"  without telemetry : {best_plain:8.2f} s wall ({best_plain / n * 1e6:6.1f} us/sample)")
    per_sample = best_recorded / n * 1e6
    print(f"  recording .rrd    : {best_recorded:8.2f} s wall ({per_sample:6.1f} us/sample), {size / 1e6:.1f} MB")
    print(f"  observer's own time: {obs:.3f} s ({obs / n * 1e6:.2f} us/sample)")
    print(f"  ratio recorded/plain: {best_recorded / best_plain:.3f} (target <= 1.25)")
    if args.emulate_us:
        grab = _Grab()
        trace = simulate(
            Plant(Payload(5.0)), circle(), TimingLaw(2.0), create("diarc"), args.duration, observers=[grab]
        )
        with tempfile.TemporaryDirectory() as folder:
            base = min(emulated(args.emulate_us, grab.run, trace, None) for _ in range(2))
            rec = min(emulated(args.emulate_us, grab.run, trace, Path(folder) / "emu.rrd") for _ in range(2))
        extra = (rec - base) / n * 1e6
        print(f"Emulated loop of {args.emulate_us:g} us/sample (busy-wait in place of the physics), best of 2")
        print(f"  plain {base:.2f} s, recording {rec:.2f} s: ratio {rec / base:.3f} (+{extra:.2f} us/sample)")


if __name__ == "__main__":
    main()
