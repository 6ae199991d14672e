"""Every fenced Python snippet of README.md and docs/*.md runs on the installed package.

Each ```python block is saved as a script and run with this interpreter in a new empty directory
(so it imports the installed gantry_twin, as a user's script would). Words after ``python`` in the
fence say what a snippet needs first:

    needs-run   a short ``gantry-twin run no_load_circle`` in that directory (runs/no_load_circle/),
                recorded to circle.rrd too
    slow        takes more than a few seconds (pytest's slow mark: the full suite runs it)
    no-run      not run: NO_RUN below says why, for each such snippet

A ```yaml block whose fence names a file (```yaml my_sweep.yaml) is written under that name into the
directory of every snippet of the same document. Shell commands are not run (they need a
terminal, a viewer or minutes); the ``gantry-twin`` commands the snippets need are run by the
fixture above through the installed console script.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCUMENTS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
MARKERS = {"needs-run", "needs-serve", "slow", "no-run"}
#: The endpoint a ``needs-serve`` snippet names; the test puts the one its server listens on in its place.
DOC_ENDPOINT = "opc.tcp://127.0.0.1:4840"
#: Snippets not run (``python no-run``), by document and first line, and why.
NO_RUN = {
    ("docs/telemetry.md", "with telemetry_observers(args) as observers:"): (
        "a fragment: `args` is the caller's argparse namespace and `...` stands for simulate's arguments"
    ),
}
#: The run a ``needs-run`` snippet reads (short: the snippets only read its files).
RUN_ARGS = [
    "run",
    "no_load_circle",
    *("--set", "duration_s=0.5", "--set", "window_s=[0.1, 0.5]", "--set", "estimates_window_s=[0.2, 0.5]"),
    *("--save", "circle.rrd", "--no-progress"),
]
FENCE = re.compile(r"^```(\w+)([^\n`]*)\n(.*?)^```\s*$", re.MULTILINE | re.DOTALL)


@dataclass(frozen=True)
class Snippet:
    document: str  # relative to the repository
    line: int
    words: frozenset[str]
    code: str

    @property
    def first_line(self) -> str:
        return self.code.strip().splitlines()[0]

    def __str__(self) -> str:
        return f"{self.document}:{self.line}"


def fenced(path: Path) -> list[tuple[str, list[str], int, str]]:
    """(language, words after it, line of the fence, body) of each fenced block of a Markdown file."""
    text = path.read_text(encoding="utf-8")
    return [
        (m.group(1), m.group(2).split(), text.count("\n", 0, m.start()) + 1, m.group(3)) for m in FENCE.finditer(text)
    ]


def snippets() -> list[Snippet]:
    found = []
    for path in DOCUMENTS:
        for language, words, line, body in fenced(path):
            if language == "python":
                found.append(Snippet(str(path.relative_to(ROOT)), line, frozenset(words), body))
    return found


def named_files(document: str) -> dict[str, str]:
    """The ```yaml NAME blocks of a document: name -> content."""
    return {words[0]: body for language, words, _, body in fenced(ROOT / document) if language == "yaml" and words}


def gantry_twin_command() -> list[str]:
    """The installed console script (beside this interpreter), else the module."""
    script = Path(sys.executable).with_name("gantry-twin")
    return [str(script)] if script.exists() else [sys.executable, "-m", "gantry_twin.cli"]


def run_in(directory: Path, command: list[str], timeout_s: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run(command, cwd=directory, capture_output=True, text=True, timeout=timeout_s, env=os.environ)


@pytest.fixture(scope="module")
def a_run(tmp_path_factory) -> Path:
    """A directory holding a short run of no_load_circle (runs/...) and its recording circle.rrd."""
    where = tmp_path_factory.mktemp("docs_run")
    done = run_in(where, [*gantry_twin_command(), *RUN_ARGS])
    assert done.returncode == 0, done.stderr
    return where


@pytest.fixture(scope="module")
def a_server(tmp_path_factory):
    """``gantry-twin serve`` on a free loopback port, running its scenario over and over; its endpoint."""
    where = tmp_path_factory.mktemp("docs_serve")
    command = [*gantry_twin_command(), "serve", "no_load_circle", "--port", "0", "--loop", "--out", str(where / "o")]
    proc = subprocess.Popen(command, cwd=where, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        match = re.search(r"(opc\.tcp://127\.0\.0\.1:\d+)", proc.stdout.readline())
        assert match is not None, "serve did not start"
        yield match.group(1)
    finally:
        proc.kill()
        proc.wait(30)


def test_the_documents_have_snippets_and_every_marker_is_known():
    found = snippets()
    assert len(found) >= 6 and {s.document for s in found} >= {"README.md", "docs/cli.md", "docs/telemetry.md"}
    for snippet in found:
        assert snippet.words <= MARKERS, f"{snippet}: unknown words {sorted(snippet.words - MARKERS)}"


def test_every_snippet_not_run_says_why_here():
    not_run = {(s.document, s.first_line) for s in snippets() if "no-run" in s.words}
    assert not_run == set(NO_RUN)


def test_no_python_in_an_indented_block():
    """Indented code blocks are not extracted: Python belongs in a ```python fence."""
    for path in DOCUMENTS:
        previous = ""
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            if previous.strip() == "" and re.match(r" {4}(from \w|import \w|>>> )", line):
                pytest.fail(f"{path.relative_to(ROOT)}:{number}: Python in an indented block; fence it as ```python")
            previous = line


def _params() -> list:
    params = []
    for snippet in snippets():
        marks = [pytest.mark.slow] if "slow" in snippet.words else []
        if "no-run" in snippet.words:
            marks.append(pytest.mark.skip(reason=NO_RUN.get((snippet.document, snippet.first_line), "no reason")))
        params.append(pytest.param(snippet, id=str(snippet), marks=marks))
    return params


@pytest.mark.parametrize("snippet", _params())
def test_the_snippet_runs(snippet: Snippet, tmp_path, request):
    for name, content in named_files(snippet.document).items():
        (tmp_path / name).write_text(content)
    if "needs-run" in snippet.words:
        made = request.getfixturevalue("a_run")
        shutil.copytree(made, tmp_path, dirs_exist_ok=True)
    code = snippet.code
    if "needs-serve" in snippet.words:
        code = code.replace(DOC_ENDPOINT, request.getfixturevalue("a_server"))
    (tmp_path / "snippet.py").write_text(code)
    done = run_in(tmp_path, [sys.executable, "snippet.py"])
    assert done.returncode == 0, f"{snippet} failed:\n{done.stderr[-3000:]}"
