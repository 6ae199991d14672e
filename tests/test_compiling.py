"""The compile notice: exact "will it compile" per install path, its line on stderr, its count on a terminal."""

from __future__ import annotations

import importlib.util
import io
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from gantry_twin.loop.compiling import EXPECTED_COMPILE_S, EXPECTED_PD_COMPILE_S, CompileNotice, compile_message
from gantry_twin.loop.simulate import compiled_available
from gantry_twin.numerics import jit

ROOT = Path(__file__).resolve().parents[1]
TINY_KERNEL = "from gantry_twin.numerics.jit import kernel\n\n\n@kernel\ndef twice(x):\n    return 2.0 * x\n"


def _load(path: Path):  # noqa: ANN202
    """The kernel ``twice`` of the module file at ``path``, imported afresh (as a new process would)."""
    spec = importlib.util.spec_from_file_location("tiny_kernel", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.twice


def test_is_cached_holds_for_the_compiled_file_only(tmp_path, monkeypatch):
    """numba's cache is per source path and content: a copy at another path, or an edited file, compiles."""
    monkeypatch.setattr(jit, "_CACHE_DIR", str(tmp_path / "cache"))
    first, second = tmp_path / "a" / "tiny_kernel.py", tmp_path / "b" / "tiny_kernel.py"
    for path in (first, second):
        path.parent.mkdir()
        path.write_text(TINY_KERNEL)
    twice = _load(first)
    assert not jit.is_cached(twice)
    assert twice(1.5) == 3.0  # compiles, and writes the cache
    assert jit.is_cached(twice) and jit.is_cached(_load(first))
    assert not jit.is_cached(_load(second))  # the same code installed at another path: numba compiles it again
    first.write_text(TINY_KERNEL + "# edited\n")
    assert not jit.is_cached(_load(first))  # an edited file (numba keeps a hash of it): the index is stale


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_the_notice_is_one_line_off_a_terminal():
    stream = io.StringIO()
    notice = CompileNotice("gantry-twin", stream)
    notice.on_start(None, None)
    notice.on_chunk(None, 0, 1)
    notice.on_end(None)
    assert stream.getvalue() == compile_message("gantry-twin") + "\n"
    assert f"about {EXPECTED_COMPILE_S} s" in stream.getvalue()


def test_the_notice_counts_seconds_on_a_terminal_until_the_first_chunk():
    stream = _Terminal()
    notice = CompileNotice("gantry-twin", stream, tick_s=0.02)
    notice.on_start(None, None)
    time.sleep(0.2)
    notice.on_chunk(None, 0, 1)
    text = stream.getvalue()
    assert text.count("\r" + compile_message("gantry-twin") + ": ") >= 3  # the first line and the thread's ticks
    assert text.endswith(" s done\n") and not notice.ticker._thread.is_alive()
    notice.on_chunk(None, 1, 2)
    notice.on_end(None)
    assert stream.getvalue() == text  # said once


def _install(where: Path) -> Path:
    """A copy of this checkout's package, model and scenarios at ``where`` (a second install path)."""
    ignore = shutil.ignore_patterns("__pycache__")
    shutil.copytree(ROOT / "src" / "gantry_twin", where / "src" / "gantry_twin", ignore=ignore)
    for folder in ("models", "scenarios"):
        shutil.copytree(ROOT / folder, where / folder, ignore=ignore)
    return where / "src"


def _python(src: Path, cache: Path, code: str, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(src), "NUMBA_CACHE_DIR": str(cache)}
    return subprocess.run(
        [sys.executable, "-c", code, *args], env=env, capture_output=True, text=True, timeout=600, cwd=src.parent
    )


RUN = "import sys; from gantry_twin.cli import main; sys.exit(main(sys.argv[1:]))"
NEEDS = (
    "from gantry_twin.controllers import PD; from gantry_twin.loop.simulate import loop_needs_compiling as n; "
    "print(n(PD()))"
)


@pytest.mark.slow
def test_a_fresh_install_path_announces_its_compile(tmp_path):
    """Empty cache, new install path: the message; same path again: none; another path on that cache: a compile."""
    if not compiled_available():
        pytest.skip("no compiled backend on this machine")
    cache, first = tmp_path / "cache", _install(tmp_path / "a")
    args = ["run", "no_load_circle", "--controller", "pd", "--set", "duration_s=0.2", "--set", "window_s=[0, 0.2]"]
    args += ["--set", "estimates_window_s=[0, 0.2]"]
    runs = [_python(first, cache, RUN, *args, "--out", str(tmp_path / f"out{i}")) for i in range(2)]
    assert [r.returncode for r in runs] == [0, 0], [r.stderr for r in runs]
    assert compile_message("gantry-twin", EXPECTED_PD_COMPILE_S) in runs[0].stderr
    assert "compiling" not in runs[1].stderr
    second = _install(tmp_path / "b")
    assert _python(first, cache, NEEDS).stdout.split() == ["False"]
    assert _python(second, cache, NEEDS).stdout.split() == ["True"]  # the first path's cache is not this one's
    again = _python(second, cache, RUN, *args, "--out", str(tmp_path / "out2"))  # the same cache, another install
    assert again.returncode == 0 and compile_message("gantry-twin", EXPECTED_PD_COMPILE_S) in again.stderr


def test_a_batch_driver_says_once_that_its_workers_compile(monkeypatch):
    """report and sweep: one line from the driver while the workers warm up, naming the loops and the time
    (DRC, DARC and DIARC share one loop; pd's is announced with its own, shorter time)."""
    from gantry_twin.controllers import create
    from gantry_twin.loop import compiling

    controllers = [create("pd"), create("diarc"), create("darc"), create("drc")]
    monkeypatch.setattr(compiling, "loop_needs_compiling", lambda c: True)
    stream = io.StringIO()
    with compiling.batch_compile_notice(controllers, "gantry-twin", stream):
        pass
    assert stream.getvalue() == (
        f"gantry-twin: workers compile the 2 loops for this install, once per worker "
        f"(about {EXPECTED_PD_COMPILE_S + EXPECTED_COMPILE_S} s) before the first result\n"
    )
    monkeypatch.setattr(compiling, "loop_needs_compiling", lambda c: c is not controllers[0])
    arc = io.StringIO()
    with compiling.batch_compile_notice(controllers, "gantry-twin", arc):
        pass
    assert f"compile the loop for this install, once per worker (about {EXPECTED_COMPILE_S} s)" in arc.getvalue()
    monkeypatch.setattr(compiling, "loop_needs_compiling", lambda c: False)
    quiet = io.StringIO()
    with compiling.batch_compile_notice(controllers, "gantry-twin", quiet):
        pass
    assert quiet.getvalue() == ""


def test_the_notice_gives_pd_its_own_shorter_time_and_a_plug_in_the_longest():
    from gantry_twin.controllers import create
    from gantry_twin.loop.compiling import expected_compile_s

    assert EXPECTED_PD_COMPILE_S < EXPECTED_COMPILE_S
    assert expected_compile_s(create("pd")) == EXPECTED_PD_COMPILE_S
    assert {expected_compile_s(create(name)) for name in ("drc", "darc", "diarc")} == {EXPECTED_COMPILE_S}
    sys.path.insert(0, str(ROOT / "examples" / "gantry-example-pd" / "src"))
    try:
        from gantry_example_pd import ExamplePD
    finally:
        sys.path.pop(0)
    assert expected_compile_s(ExamplePD()) == EXPECTED_COMPILE_S  # a plug-in's step: its size is unknown


def test_a_batch_driver_counts_seconds_on_a_terminal_while_its_workers_warm_up(monkeypatch):
    from gantry_twin.loop import compiling

    monkeypatch.setattr(compiling, "loop_needs_compiling", lambda c: True)
    stream = _Terminal()
    with compiling.batch_compile_notice(["diarc"], "gantry-twin", stream, tick_s=0.02):
        time.sleep(0.2)
    line = "\r" + compiling.workers_compile_message("gantry-twin", 1, EXPECTED_COMPILE_S) + ": "
    text = stream.getvalue()
    assert text.count(line) >= 3 and text.endswith(" s done\n")


def test_excite_says_when_its_loop_compiles(tmp_path, monkeypatch):
    """excite runs its trajectory under PD: a first compile of that loop is announced like a run's."""
    from gantry_twin.cli import main
    from gantry_twin.loop import compiling

    monkeypatch.setattr(compiling, "loop_needs_compiling", lambda c: True)
    stream = io.StringIO()
    monkeypatch.setattr(sys, "stderr", stream)
    assert main(["excite", "--out", str(tmp_path / "e"), "--duration-s", "4", "--fade-s", "1"]) == 0
    assert stream.getvalue().count(compile_message("gantry-twin", EXPECTED_PD_COMPILE_S)) == 1
    monkeypatch.setattr(compiling, "loop_needs_compiling", lambda c: False)
    quiet = io.StringIO()
    monkeypatch.setattr(sys, "stderr", quiet)
    assert main(["excite", "--out", str(tmp_path / "f"), "--duration-s", "4", "--fade-s", "1"]) == 0
    assert "compiling" not in quiet.getvalue()


def test_monitor_log_says_when_the_estimator_replay_compiles(monkeypatch):
    from gantry_twin.cli import monitor

    for cached, expected in ((False, True), (True, False)):
        monkeypatch.setattr(monitor, "is_cached", lambda f, cached=cached: cached)
        stream = io.StringIO()
        assert monitor.replay_compile_notice("gantry-twin", stream) is expected
        assert ("compiling the estimator's replay" in stream.getvalue()) is expected
