"""A fuzz target per reader of a user's file: whatever the bytes, the reader returns a value or raises its one
documented error, one line; never another exception type (a traceback), never a hang.

The readers: a scenario file (``load_scenario`` then ``build``, as ``run`` and ``validate`` do), a sweep file
(``load_sweep``), a calibration file (``load_calibration``): ScenarioError; a log (``read_log``): LogError; a
run's summary.json (``RunSummary.read``): SummaryError. G-code has its own target in tests/test_gcode_reader.py
(``test_any_input_is_a_program_or_one_gcode_error``). Inputs are random bytes, text of each format's
characters, and valid files cut, spliced and mutated (where most of the readers' branches are). Each target
runs FUZZ_EXAMPLES examples here (a few seconds), EXHAUSTIVE_EXAMPLES under ``-m exhaustive``. "Never a hang":
an example that takes longer than EXAMPLE_LIMIT_S of wall time fails (SIGALRM).
"""

from __future__ import annotations

import contextlib
import json
import signal
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gantry_twin.calibration import load_calibration
from gantry_twin.outputs.summary import RunSummary, SummaryError
from gantry_twin.scenario import ScenarioError, build, load_scenario, shipped
from gantry_twin.sweep import load_sweep
from gantry_twin.sysid.logs import LogError, read_log

FUZZ_EXAMPLES = 60
EXHAUSTIVE_EXAMPLES = 2000
EXAMPLE_LIMIT_S = 10

SCENARIO = shipped("step_disturbance_circle").read_text(encoding="utf-8")
SWEEP = (Path(__file__).resolve().parents[1] / "sweeps" / "payload_0_20kg.yaml").read_text(encoding="utf-8")
CALIBRATION = (Path(__file__).resolve().parents[1] / "calibrations" / "paper_circle_set1.yaml").read_text("utf-8")
LOG = "t_s,u_x_v,u_y_v,x_m,y_m,x_d_m\n" + "".join(
    f"{k * 2e-4!r},{0.1 * (k % 7) - 0.3:.3f},-0.2,{1e-6 * k:.9f},{-2e-6 * k:.9f},0.0\n" for k in range(40)
)
SUMMARY = json.dumps(
    {
        "schema_version": 1,
        "controller": "diarc",
        "duration_s": 1.0,
        "sample_period_s": 2e-4,
        "steps": 5000,
        "status": "ok",
        "contour_error_um": {"window_s": [0.5, 1.0], "rms": 1.2, "max": 3.4},
        "end_stop_contacts": {"x": 0, "y": 0},
    }
)

YAML_CHARS = "abcdefghijklmnopqrstuvwxyz_.:-[]{},&*!|>#'\"%@` \n\t0123456789+eE"
CSV_CHARS = "t_suxyvdm,.-+eE0123456789nainf \n\r\"'"
JSON_CHARS = '{}[]":,.-+eE0123456789 \ntruefalsnulNaInfity_abcdghkmopqrsvwxyz'


def mutated(seed: str, chars: str) -> st.SearchStrategy[bytes]:
    """``seed`` with up to six edits (a slice deleted, replaced or duplicated, characters inserted), as bytes; or
    text of the format's characters; or random bytes."""

    @st.composite
    def edits(draw: st.DrawFn) -> bytes:
        text = seed
        for _ in range(draw(st.integers(0, 6))):
            i = draw(st.integers(0, len(text)))
            j = draw(st.integers(i, min(len(text), i + 40)))
            kind = draw(st.sampled_from(["delete", "replace", "duplicate", "insert"]))
            new = draw(st.text(alphabet=chars, max_size=12))
            if kind == "delete":
                text = text[:i] + text[j:]
            elif kind == "replace":
                text = text[:i] + new + text[j:]
            elif kind == "duplicate":
                text = text[:j] + text[i:j] * draw(st.integers(1, 3)) + text[j:]
            else:
                text = text[:i] + new + text[i:]
        return text.encode("utf-8")

    return st.one_of(edits(), st.text(alphabet=chars, max_size=300).map(str.encode), st.binary(max_size=300))


@contextlib.contextmanager
def bounded(seconds: int = EXAMPLE_LIMIT_S) -> Iterator[None]:
    """Fail (TimeoutError) an example that runs longer than ``seconds`` of wall time."""

    def expire(signum, frame):  # noqa: ANN001
        raise TimeoutError(f"a reader ran past {seconds} s: a hang")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def check_reader(data: bytes, name: str, read: Callable[[Path], object], error: type[Exception]) -> None:
    """``read`` of a file holding ``data`` returns, or raises ``error`` with a one-line message naming the file."""
    with tempfile.TemporaryDirectory(prefix="gantry-twin-fuzz-") as tmp:
        path = Path(tmp) / name
        path.write_bytes(data)
        try:
            with bounded():
                read(path)
        except error as exc:
            message = str(exc)
            assert message and "\n" not in message.strip(), message
            assert str(path) in message or name in message, message


def _scenario(path: Path) -> None:
    build(load_scenario(path), str(path))


READERS = {
    "scenario": (SCENARIO, YAML_CHARS, "s.yaml", _scenario, ScenarioError),
    "sweep": (SWEEP, YAML_CHARS, "w.yaml", load_sweep, ScenarioError),
    "calibration": (CALIBRATION, YAML_CHARS, "c.yaml", load_calibration, ScenarioError),
    "log": (LOG, CSV_CHARS, "log.csv", read_log, LogError),
    "summary": (SUMMARY, JSON_CHARS, "summary.json", RunSummary.read, SummaryError),
}


def _target(kind: str, examples: int):
    seed, chars, name, read, error = READERS[kind]

    @settings(max_examples=examples, deadline=None, suppress_health_check=[HealthCheck.too_slow])
    @given(mutated(seed, chars))
    def target(data: bytes) -> None:
        check_reader(data, name, read, error)

    return target


@pytest.mark.parametrize("kind", READERS)
def test_reader_returns_or_raises_its_one_line_error(kind):
    _target(kind, FUZZ_EXAMPLES)()


@pytest.mark.exhaustive
@pytest.mark.parametrize("kind", READERS)
def test_reader_returns_or_raises_its_one_line_error_exhaustively(kind):
    _target(kind, EXHAUSTIVE_EXAMPLES)()


@pytest.mark.parametrize("kind", READERS)
def test_the_seed_reads_and_a_broken_one_is_refused(kind):
    """The targets start from files that read (so the mutations reach the deep checks), and check_reader fails
    when a reader leaks another exception type (so the targets can fail)."""
    seed, _, name, read, error = READERS[kind]
    check_reader(seed.encode(), name, read, error)

    def leaks(path: Path) -> None:
        raise KeyError("not the documented error")

    with pytest.raises(KeyError):
        check_reader(seed.encode(), name, leaks, error)
