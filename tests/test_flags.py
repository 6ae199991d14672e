"""One flag vocabulary across the commands: --workers, --out, --set, --controller, --progress; export's default
format; the shipped sweeps listed; a finished sweep's re-run told how to start afresh."""

from __future__ import annotations

import pytest

from gantry_twin.cli.app import build_parser
from gantry_twin.sweep.listing import shipped_sweeps

from .helpers import run_main

SHARED = {
    "--out": ["run", "monitor", "report", "sweep", "compare", "export"],
    "--workers": ["report", "sweep"],
    "--set": ["run", "monitor", "validate", "report"],
    "--controller": ["run", "monitor", "validate"],
    "--progress": ["run", "monitor", "report", "sweep"],
}


def _subparsers():
    parser = build_parser()
    action = next(a for a in parser._actions if a.dest == "command")
    return action.choices


@pytest.mark.parametrize(("flag", "commands"), SHARED.items(), ids=list(SHARED))
def test_shared_flags_have_one_name_on_every_command(flag, commands):
    choices = _subparsers()
    for command in commands:
        options = {o for a in choices[command]._actions for o in a.option_strings}
        assert flag in options, (command, flag)


def test_report_jobs_is_a_hidden_deprecated_alias_of_workers(tmp_path, capsys):
    assert "--jobs" not in choices_help("report")
    assert "--workers" in choices_help("report")
    code, _, err = run_main(["report", "--jobs", "0", "--out", str(tmp_path / "r")], capsys)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 2
    assert "--jobs is deprecated, use --workers" in lines[0]
    assert "--jobs: must be a positive integer" in lines[1]
    assert not (tmp_path / "r").exists()


def choices_help(command: str) -> str:
    return _subparsers()[command].format_help()


def test_docs_table_names_every_shared_flag():
    from pathlib import Path

    text = (Path(__file__).parents[1] / "docs" / "cli.md").read_text()
    table = text.split("## Shared flags", 1)[1].split("\n## ", 1)[0]
    for flag in SHARED:
        assert f"`{flag}" in table, flag


def test_sweeps_lists_every_shipped_sweep_on_one_line(capsys):
    code, out, err = run_main(["sweeps"], capsys)
    lines = out.strip().splitlines()
    assert code == 0 and not err
    assert [line.split()[0] for line in lines] == [p.stem for p in shipped_sweeps()]
    assert all(len(line.split(None, 1)) == 2 for line in lines)


def test_a_finished_sweep_rerun_says_how_to_start_afresh(tmp_path, capsys):
    out = tmp_path / "s"
    out.mkdir()
    (out / "results.parquet").write_bytes(b"")
    code, _, err = run_main(["sweep", "payload_0_20kg", "--out", str(out)], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert f"gantry-twin sweep payload_0_20kg --out {out} --fresh" in err
    assert f"gantry-twin sweep payload_0_20kg --out {out} --resume" in err
