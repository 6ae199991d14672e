"""The live mode: LinuxCNC runs with the twin as its machine, in real time (docs/linuxcnc.md, "The live mode").

LinuxCNC's HAL file (:func:`gantry_twin.cnc.config.live_hal_text`) loads the
twin as a userspace program. The twin talks to HAL through HAL's own
programs, never its library (the twin stays a separate program):

* **Commands in.** ``sampler.0`` takes, every servo period T (1 ms), the X
  and Y ``joint.N.motor-pos-cmd`` (mm), LinuxCNC's estop chain
  (``iocontrol.0.user-enable-out``), ``motion.motion-enabled`` and the tag of
  the streamer's row out in that period; ``halsampler -t`` (line-buffered) prints them, the sample
  number first. :class:`LiveCommands` reads them and is the loop's
  :class:`~gantry_twin.paths.contours.TimedContour`: its reference at t is
  the cubic Hermite (Catmull-Rom) curve through the commands, each
  command's slope the central difference of its neighbours,
  ``v_k = (q_{k+1} - q_{k-1}) / 2T`` (one-sided at the first): it passes
  through every command, its velocity is continuous, its acceleration and
  jerk are its exact derivatives (piecewise linear and constant). It is
  causal with a lookahead of :data:`LOOKAHEAD_PERIODS` servo periods: the
  reference on [kT, (k+1)T) needs the commands up to k + 2, so the twin's time
  trails LinuxCNC's by that and by a chunk of the loop (:data:`CHUNK_S`).
  While motion is disabled, LinuxCNC copies its feedback (then the twin's
  measured position) into its command: the twin holds the last enabled
  command instead of chasing its own position through the FIFOs' delay.
  alpha is the direction of the reference's velocity; below
  :data:`DIRECTION_SPEED_M_S` it holds its last value (alpha' = alpha'' = 0).
* **Errors out.** After each chunk of the loop, :class:`LiveFeedback` writes
  one row per servo instant to ``halstreamer``: the twin's error
  ``e_k = q_meas(kT) - q_cmd_k`` (mm, the encoder's reading less the
  command), an ok bit, a heartbeat that toggles each row and the tag k.
  HAL adds e to the command (``sum2``): LinuxCNC's ``motor-pos-fb`` is the
  command plus the twin's error, so its following error is the twin's
  tracking error, only older by the FIFO's delay, and never the delay
  itself (which a position fed back through the FIFOs would add: the
  command's travel in the delay, 1.7 mm at 1 m/min and 100 ms).
* **The delay.** The streamer is prefilled with ``delay_periods`` D rows
  (e = 0) and enabled in the same servo period as the sampler (one HAL
  signal), so the row of command k comes out D periods after k was taken
  (more after each underrun, when the twin was late). The sampler records
  the tag of the row out in each period: the delay is measured, per period,
  as the sample number less that tag (:attr:`LiveCommands.delay_histogram`).
* **Faults.** An end-stop contact (:func:`gantry_twin.loop.events.end_stop_zones`)
  or a failed loop ends the run and the twin's rows say not ok: HAL's
  ``watchdog`` then opens LinuxCNC's estop chain; a dead twin stops the
  heartbeat and the watchdog opens it too. LinuxCNC's estop (its chain out
  falling after it was closed) and LinuxCNC's exit (the sampler's end) end
  the twin's run cleanly (:class:`~gantry_twin.paths.contours.ReferenceEnded`).
"""

from __future__ import annotations

import json
import math
import os
import selectors
import subprocess
import time
from pathlib import Path

import numpy as np

from gantry_twin.cnc.session import HALCMD
from gantry_twin.gcode.sampling import Samples, timed_contour_error
from gantry_twin.loop.events import end_stop_zones
from gantry_twin.loop.trace import RunInfo, Trace
from gantry_twin.numerics import libm
from gantry_twin.paths.contours import Reference, ReferenceEnded
from gantry_twin.plant.model import AXES, Plant

#: The loop's chunk in the live mode, s: the errors go back after each.
CHUNK_S = 0.05
#: The contour error's search about the desired time (window, coarse step, fine step; s): the twin trails its
#: command by far less than the window (its tracking error over the speed).
SEARCH_S = (0.003, 1e-3, 5e-4)
#: The reference on [kT, (k+1)T) needs the commands up to k + LOOKAHEAD_PERIODS (Catmull-Rom: the one after next).
LOOKAHEAD_PERIODS = 2
#: Below this speed of the reference, alpha holds its last value (m/s).
DIRECTION_SPEED_M_S = 0.005
#: Servo periods of commands held (the reference and the contour error look back less than a second).
HISTORY_PERIODS = 4096
#: Default rows prefilled into the streamer (the delay of the twin's errors, servo periods).
DELAY_PERIODS = 100
#: Wall seconds the twin waits for a command before it says LinuxCNC stalled and ends.
STALL_S = 30.0
#: Largest delay histogram bin, servo periods.
DELAY_BINS = 1 << 14
#: The live mode's side of the run directory.
LIVE_FILE = "linuxcnc_live.json"


class LiveError(RuntimeError):
    """The live link could not start or broke (one line)."""


class LiveFifos:
    """HAL's programs at the twin's end of the FIFOs: ``halsampler`` (commands in) and ``halstreamer`` (errors out),
    started by the twin and stopped by :meth:`close` (LinuxCNC's exit ends them first: HAL unloads them)."""

    def __init__(self, delay_periods: int = DELAY_PERIODS) -> None:
        self.delay_periods = delay_periods
        self.sampler: subprocess.Popen | None = None
        self.streamer: subprocess.Popen | None = None
        self._buffer = b""
        self._selector = selectors.DefaultSelector()
        self.heartbeat = 0
        self._started: tuple[float, float] | None = None  # (wall s, CPU s) when the commands began to flow
        self.cpu: dict[str, float] = {}

    @staticmethod
    def check() -> None:
        """LiveError unless a HAL session of the live configuration runs (its streamer and sampler exist)."""
        for pin in ("streamer.0.curr-depth", "sampler.0.curr-depth"):
            try:
                done = subprocess.run([HALCMD, "getp", pin], capture_output=True, text=True, timeout=10)
            except (OSError, subprocess.TimeoutExpired) as exc:
                raise LiveError(f"HAL's halcmd cannot run ({exc})") from None
            if done.returncode:
                raise LiveError(
                    f"no HAL session of the live configuration runs here (halcmd getp {pin} failed): the live "
                    "configuration's HAL file starts this command when LinuxCNC starts"
                )

    @property
    def started(self) -> bool:
        return self._started is not None

    def start(self) -> None:
        """Start both programs, prefill the streamer and enable the sampler and the streamer in one period."""
        self.sampler = subprocess.Popen(
            ["stdbuf", "-oL", "halsampler", "-c", "0", "-t"], stdin=subprocess.DEVNULL, stdout=subprocess.PIPE
        )
        self.streamer = subprocess.Popen(["halstreamer", "-c", "0"], stdin=subprocess.PIPE, text=True)
        self._selector.register(self.sampler.stdout, selectors.EVENT_READ)
        self.write([(0.0, 0.0, 0.0, 0.0, True, -1)] * self.delay_periods)
        deadline = time.monotonic() + 10.0
        while _getp("streamer.0.curr-depth") != str(self.delay_periods):
            if time.monotonic() > deadline or self.streamer.poll() is not None:
                raise LiveError(f"HAL's streamer did not take the {self.delay_periods} prefilled rows")
            time.sleep(0.01)
        subprocess.run([HALCMD, "sets", "gantry-twin-run", "1"], check=True, capture_output=True, timeout=10)
        self._started = (time.monotonic(), self._cpu_s())

    def _cpu_s(self) -> float:
        """CPU seconds so far, user and system, of this process (every thread) and of its HAL programs (read from
        /proc while they run or before they are reaped)."""
        times = os.times()
        total = times.user + times.system
        for process in (self.sampler, self.streamer):
            try:
                fields = Path(f"/proc/{process.pid}/stat").read_text().rsplit(")", 1)[1].split()
                total += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
            except (AttributeError, OSError, IndexError, ValueError):
                continue
        return total

    def mark_end(self) -> None:
        """The commands stopped: the twin's CPU from their start to here (:attr:`cpu`), once."""
        if self._started is not None and not self.cpu:
            wall, cpu = time.monotonic() - self._started[0], self._cpu_s() - self._started[1]
            self.cpu = {"wall_s": wall, "cpu_s": cpu, "cpu_fraction": cpu / wall if wall > 0 else 0.0}

    def write(self, rows) -> None:
        """Rows (e_x, e_y, p_x, p_y mm, ok, tag) to the streamer, each with the next heartbeat."""
        if self.streamer is None or self.streamer.stdin is None:
            return  # not started
        lines = []
        for ex, ey, px, py, ok, tag in rows:
            self.heartbeat ^= 1
            lines.append(f"{ex:.9f} {ey:.9f} {px:.9f} {py:.9f} {int(ok)} {self.heartbeat} {int(tag)}\n")
        try:
            self.streamer.stdin.write("".join(lines))
            self.streamer.stdin.flush()
        except (BrokenPipeError, ValueError):
            pass  # LinuxCNC is ending: the sampler's end says so

    def read(self, timeout_s: float) -> tuple[list[bytes], bool]:
        """The complete lines the sampler printed within ``timeout_s`` (at least one, unless it ended or the
        time passed), and whether it ended."""
        assert self.sampler is not None and self.sampler.stdout is not None
        fd = self.sampler.stdout.fileno()
        deadline = time.monotonic() + timeout_s
        while True:
            ended = False
            if self._selector.select(max(0.0, deadline - time.monotonic())):
                chunk = os.read(fd, 1 << 16)
                ended = not chunk
                self._buffer += chunk
            *lines, self._buffer = self._buffer.split(b"\n")
            if lines or ended or time.monotonic() >= deadline:
                return lines, ended

    def close(self) -> None:
        """Stop both programs (the streamer after its last rows are in the FIFO)."""
        self.mark_end()
        if self.streamer is not None:
            try:
                if self.streamer.stdin is not None:
                    self.streamer.stdin.close()
            except (BrokenPipeError, ValueError, OSError):
                pass
            _end(self.streamer)
        if self.sampler is not None:
            _end(self.sampler)
        self._selector.close()


def _end(process: subprocess.Popen) -> None:
    try:
        process.wait(2.0)
    except subprocess.TimeoutExpired:
        process.terminate()
        try:
            process.wait(5.0)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(5.0)


def _getp(name: str) -> str:
    done = subprocess.run([HALCMD, "getp", name], capture_output=True, text=True, timeout=10)
    return done.stdout.strip()


class LiveCommands:
    """LinuxCNC's commands as they come: the loop's reference (a ``TimedContour``, phi = t, t = 0 at the first
    command sampled) and the delay measured from the streamer's tags (module docstring)."""

    def __init__(self, fifos: LiveFifos, servo_period_s: float) -> None:
        self.fifos, self.period_s = fifos, servo_period_s
        self.first = 0  # the sample number of self._q[0]
        self._q = np.zeros((0, 2))
        self._ok_seen = False
        self.ended_by: str | None = None
        self.stop_reason: str | None = None  # set by the feedback on a fault: the run ends at the next chunk
        self.overruns = 0
        self.delay_histogram = np.zeros(DELAY_BINS, dtype=np.int64)
        self._alpha_last = 0.0
        self._hold = np.zeros(2)  # the command the twin holds while LinuxCNC's motion is disabled, m

    @property
    def count(self) -> int:
        """Commands received so far."""
        return self.first + len(self._q)

    @property
    def duration_s(self) -> float:
        return max(self.count - 1, 0) * self.period_s

    @property
    def period_rad(self) -> float:
        return 1.0

    def derivatives(self, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        s = self.sample(np.asarray(phi, dtype=float))
        return s.q_m, s.v_m_s, s.a_m_s2, s.j_m_s3

    # ------------------------------------------------------------------ reading
    def _need(self, index: int) -> None:
        """Read until command ``index`` is in, or raise ReferenceEnded (LinuxCNC ended, its estop, a fault)."""
        while self.count <= index:
            if self.stop_reason is not None or self.ended_by is not None:
                self.fifos.mark_end()
                raise ReferenceEnded(self.stop_reason or self.ended_by)
            missing = index + 1 - self.count
            if missing > 2:  # they come one a period: sleep until nearly all are in, not awake for each line
                time.sleep(min(missing - 2, 200) * self.period_s)
            lines, ended = self.fifos.read(STALL_S)
            if lines:
                self._take(lines)
            elif ended:
                self.ended_by = "LinuxCNC ended (HAL's sampler closed)"
            else:
                self.ended_by = f"no command from LinuxCNC for {STALL_S:g} s"
        if self.stop_reason is not None:
            self.fifos.mark_end()
            raise ReferenceEnded(self.stop_reason)

    def _take(self, lines: list[bytes]) -> None:
        rows = []
        for line in lines:
            words = line.split()
            if not words:
                continue
            if words[0] == b"overrun":
                self.overruns += 1
                self.stop_reason = "HAL's sampler overran: the twin fell a FIFO's depth behind LinuxCNC"
                break
            rows.append([float(w) for w in words[:6]])
        if not rows:
            return
        data = np.asarray(rows)
        if self.count == 0 and data[0, 0] != 0:
            self.first = int(data[0, 0])
        enable = data[:, 3] > 0.5
        if not self._ok_seen and enable.any():
            self._ok_seen = True
            enable[: int(np.argmax(enable))] = True
        if self._ok_seen and not enable.all():  # LinuxCNC's estop: the commands after it are not the machine's
            data = data[: int(np.argmin(enable))]
            self.ended_by = "LinuxCNC's estop (iocontrol.0.user-enable-out fell)"
        echo = data[:, 5].astype(np.int64)
        delay = data[:, 0].astype(np.int64) - echo
        valid = (echo >= 0) & (delay >= 0) & (delay < DELAY_BINS)
        self.delay_histogram += np.bincount(delay[valid], minlength=DELAY_BINS)[:DELAY_BINS]
        q = np.concatenate([self._q, self._held(data[:, 1:3] * 1e-3, data[:, 4] > 0.5)])
        if len(q) > 2 * HISTORY_PERIODS:
            drop = len(q) - HISTORY_PERIODS
            q, self.first = q[drop:], self.first + drop
        self._q = q

    def _held(self, q: np.ndarray, enabled: np.ndarray) -> np.ndarray:
        """The commands with those taken while motion was disabled replaced by the last enabled one (motion then
        copies the feedback, the twin's own position, into its command: the twin would chase itself)."""
        source = np.maximum.accumulate(np.where(enabled, np.arange(len(q)), -1))
        out = np.where((source >= 0)[:, None], q[np.maximum(source, 0)], self._hold)
        self._hold = out[-1].copy()
        return out

    # ------------------------------------------------------------------ the loop's reference
    def reference(self, t_s: np.ndarray) -> Reference:
        t = np.asarray(t_s, dtype=float)
        self._need(int(math.floor(t[-1] / self.period_s + 1e-9)) + LOOKAHEAD_PERIODS)
        q, v, a, j = self._hermite(t)
        speed2 = np.einsum("ij,ij->i", v, v)
        moving = speed2 >= DIRECTION_SPEED_M_S**2
        raw = libm.atan2(v[:, 1], v[:, 0])
        source = np.maximum.accumulate(np.where(moving, np.arange(len(t)), -1))
        held = np.where(source >= 0, raw[np.maximum(source, 0)], self._alpha_last)
        alpha = np.unwrap(np.concatenate([[self._alpha_last], held]))[1:]
        self._alpha_last = float(alpha[-1])
        safe = np.where(moving, speed2, 1.0)
        cross_a = v[:, 0] * a[:, 1] - v[:, 1] * a[:, 0]
        cross_j = v[:, 0] * j[:, 1] - v[:, 1] * j[:, 0]
        dot = np.einsum("ij,ij->i", v, a)
        dalpha = np.where(moving, cross_a / safe, 0.0)
        ddalpha = np.where(moving, (cross_j * safe - 2.0 * cross_a * dot) / safe**2, 0.0)
        return Reference(
            t_s=t, phi=t.copy(), dphi=np.ones_like(t), q_d=q, dq_d=v, ddq_d=a, alpha=alpha, dalpha=dalpha,
            ddalpha=ddalpha,
        )  # fmt: skip

    def sample(self, t_s: np.ndarray) -> Samples:
        """The reference at times t_s (s) among the commands held (held at their ends outside them); alpha
        from the velocity (the last alpha below DIRECTION_SPEED_M_S): for the contour error's sign."""
        t = np.asarray(t_s, dtype=float).reshape(-1)
        q, v, a, j = self._hermite(t)
        moving = np.einsum("ij,ij->i", v, v) >= DIRECTION_SPEED_M_S**2
        alpha = np.where(moving, libm.atan2(v[:, 1], v[:, 0]), self._alpha_last)
        zero = np.zeros(len(t))
        return Samples(t, q, v, a, j, alpha, zero, zero.copy(), np.zeros(len(t), dtype=np.int64))

    def contour_error(self, q_m: np.ndarray, phi_guess: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """eps_c against the commanded path received so far (:func:`gantry_twin.gcode.sampling.timed_contour_error`)."""
        return timed_contour_error(self.sample, self.duration_s, q_m, phi_guess, *SEARCH_S)

    def _hermite(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The Catmull-Rom curve through the commands held and its first three time derivatives at t (m, s)."""
        T, count, q = self.period_s, self.count, self._q
        if len(q) == 0:
            zero = np.zeros((len(t), 2))
            return zero, zero.copy(), zero.copy(), zero.copy()
        lo, hi = self.first, count - 1
        x = np.clip(t / T, lo, hi)
        k = np.clip(np.floor(x).astype(np.int64), lo, max(hi - 1, lo))
        u = (x - k)[:, None]
        rows = (k - lo)[:, None] + np.arange(-1, 3)  # k - 1 .. k + 2, held at the ends
        near = np.take(q, rows, axis=0, mode="clip")
        p0, p1, p2, p3 = near[:, 0], near[:, 1], near[:, 2], near[:, 3]
        m1, m2 = 0.5 * (p2 - p0), 0.5 * (p3 - p1)
        first = (k == 0)[:, None]  # the first command: its slope one-sided
        m1 = np.where(first, p2 - p1, m1)
        c = 3.0 * (p2 - p1) - 2.0 * m1 - m2
        d = 2.0 * (p1 - p2) + m1 + m2
        pos = p1 + u * (m1 + u * (c + u * d))
        vel = (m1 + u * (2.0 * c + 3.0 * u * d)) / T
        acc = (2.0 * c + 6.0 * u * d) / T**2
        jerk = np.broadcast_to(6.0 * d / T**3, pos.shape).copy()
        outside = (t / T < lo) | (t / T > hi)
        vel[outside], acc[outside], jerk[outside] = 0.0, 0.0, 0.0
        return pos, vel, acc, jerk

    def held(self) -> HeldCommands:
        """The commands received so far as a contour that never waits (for telemetry: :class:`HeldCommands`)."""
        return HeldCommands(self)

    # ------------------------------------------------------------------ what it measured
    def delay_periods(self) -> dict[str, float | int]:
        """The delay of the twin's errors, servo periods (median, p99, min, max over the periods measured)."""
        h = self.delay_histogram
        n = int(h.sum())
        if n == 0:
            return {"periods_measured": 0}
        cumulative = np.cumsum(h)
        nonzero = np.flatnonzero(h)
        return {
            "periods_measured": n,
            "median": int(np.searchsorted(cumulative, 0.5 * n)),
            "p99": int(np.searchsorted(cumulative, 0.99 * n)),
            "min": int(nonzero[0]),
            "max": int(nonzero[-1]),
        }

    def run_files(self) -> dict[str, str]:
        """The live mode's side of the run directory (:data:`LIVE_FILE`)."""
        return {LIVE_FILE: json.dumps(self.info(), indent=2) + "\n"}

    def info(self) -> dict:
        """What the link did: the commands, how it ended, the delay measured (servo periods and ms)."""
        delay = self.delay_periods()
        return {
            "cnc": "linuxcnc",
            "mode": "live",
            "servo_period_s": self.period_s,
            "commands": self.count,
            "covered_s": self.duration_s,
            "ended_by": self.stop_reason or self.ended_by or "the twin's duration",
            "prefill_periods": self.fifos.delay_periods,
            "delay_periods": delay,
            "delay_ms": {k: v * self.period_s * 1e3 for k, v in delay.items() if k != "periods_measured"},
            "sampler_overruns": self.overruns,
            # each underrun delays every later row by one period, and nothing shortens the delay
            "streamer_underruns": delay["max"] - self.fifos.delay_periods if "max" in delay else 0,
            "twin_cpu": self.fifos.cpu,  # from the commands' start to their end
        }


class HeldCommands:
    """The commands received so far as a ``TimedContour`` that never waits for more (held at the last one): what
    a telemetry observer may draw and measure against while the loop runs (phi = t)."""

    def __init__(self, commands: LiveCommands) -> None:
        self.commands = commands

    @property
    def period_rad(self) -> float:
        return 1.0

    def derivatives(self, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        return self.commands.derivatives(phi)

    def reference(self, t_s: np.ndarray) -> Reference:
        s = self.commands.sample(t_s)
        return Reference(
            t_s=s.t_s, phi=s.t_s.copy(), dphi=np.ones_like(s.t_s), q_d=s.q_m, dq_d=s.v_m_s, ddq_d=s.a_m_s2,
            alpha=s.alpha_rad, dalpha=s.dalpha_rad_s, ddalpha=s.ddalpha_rad_s2,
        )  # fmt: skip

    def contour_error(self, q_m: np.ndarray, phi_guess: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.commands.contour_error(q_m, phi_guess)


class LiveFeedback:
    """The loop's observer that writes the twin's error back to LinuxCNC at every servo instant of each chunk
    (module docstring) and watches for the faults that must raise LinuxCNC's estop."""

    def __init__(self, commands: LiveCommands, plant: Plant, report=print) -> None:
        self.commands, self.report = commands, report
        self.ratio = int(round(commands.period_s / plant.timestep_s))
        _, self.lower_m, self.upper_m = end_stop_zones(plant)
        self.fault: str | None = None
        self.rows_written = 0
        self.last_mm = np.zeros(2)  # the twin's last measured position, mm

    def on_start(self, run: RunInfo, trace: Trace) -> None:
        pass

    def on_chunk(self, trace: Trace, start: int, stop: int) -> None:
        first = -(-start // self.ratio) * self.ratio
        ks = np.arange(first, stop, self.ratio)
        if self.fault is None:
            rows = trace.rows(start, stop)
            q = trace.q_m[rows]
            touching = (q < self.lower_m) | (q > self.upper_m)
            if touching.any():
                i, axis = np.argwhere(touching)[0]
                t = float(trace.t_s[rows][i])
                self.set_fault(f"{AXES[axis]} touched its end stop at t = {t:.4f} s ({1e3 * q[i, axis]:+.3f} mm)")
        if ks.size == 0:
            return
        idx = ks - trace.first
        p_mm = trace.q_meas_m[idx] * 1e3
        e_mm = p_mm - trace.q_d_m[idx] * 1e3
        ok = self.fault is None
        tags = ks // self.ratio  # the servo sample's number: t = 0 is the sampler's first
        self.last_mm = p_mm[-1]
        self.commands.fifos.write([(*e, *p, ok, tag) for e, p, tag in zip(e_mm, p_mm, tags, strict=True)])
        self.rows_written += ks.size

    def set_fault(self, reason: str) -> None:
        """A fault of the twin: LinuxCNC's estop through the streamer's ok bit, and the run ends."""
        if self.fault is None:
            self.fault = reason
            self.commands.stop_reason = f"the twin's fault: {reason}"
            self.report(f"gantry-twin: the twin's fault raises LinuxCNC's estop: {reason}")
            self.commands.fifos.write([(0.0, 0.0, *self.last_mm, False, -1)] * 2)

    def on_end(self, trace: Trace) -> None:
        pass
