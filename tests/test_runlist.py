"""gantry-twin runs (gantry_twin.outputs.runlist): the runs under runs/ and a prune that keeps the last N."""

from __future__ import annotations

import json
import os

from gantry_twin.outputs.runlist import list_runs, to_prune

from .helpers import run_main

NAMES = ["20261201T010000Z-aaaaaa", "20261201T020000Z-bbbbbb", "20261201T030000Z-cccccc", "20261201T040000Z-dddddd"]


def _runs(tmp_path, latest: str):
    runs = tmp_path / "runs"
    for i, name in enumerate(NAMES):
        d = runs / "no_load_circle" / name
        d.mkdir(parents=True)
        if i != 3:  # the last one never finished
            (d / "summary.json").write_text(json.dumps({"status": "failed" if i == 2 else "ok"}))
        (d / "trace.parquet").write_bytes(b"x" * 1000 * (i + 1))
    os.symlink(latest, runs / "no_load_circle" / "latest")
    (runs / "report").mkdir()  # not a scenario's run directory
    return runs


def test_runs_lists_size_status_time_and_latest(tmp_path, capsys):
    runs = _runs(tmp_path, NAMES[1])
    code, out, err = run_main(["runs", "--dir", str(runs)], capsys)
    lines = out.strip().splitlines()
    assert code == 0 and not err and len(lines) == 5
    assert (
        lines[0].startswith(f"no_load_circle/{NAMES[0]}") and "ok" in lines[0] and "2026-12-01 01:00:00 UTC" in lines[0]
    )
    assert "(latest)" in lines[1] and "failed" in lines[2] and "incomplete" in lines[3]
    assert "1.0 kB" in lines[0] and lines[-1].startswith("4 runs")


def test_prune_is_a_dry_run_without_yes_and_never_deletes_latest(tmp_path, capsys):
    runs = _runs(tmp_path, NAMES[0])
    doomed = to_prune(list_runs(runs), keep=2)
    assert [e.path.name for e in doomed] == [NAMES[1]]  # NAMES[0] is latest's target
    code, out, err = run_main(["runs", "--dir", str(runs), "--prune", "--keep", "2"], capsys)
    assert code == 0 and "would delete" in out and "--yes" in err
    assert all((runs / "no_load_circle" / n).is_dir() for n in NAMES)
    code, out, _ = run_main(["runs", "--dir", str(runs), "--prune", "--keep", "2", "--yes"], capsys)
    assert code == 0 and f"deleted no_load_circle/{NAMES[1]}" in out
    assert sorted(p.name for p in (runs / "no_load_circle").iterdir()) == sorted([*NAMES[:1], *NAMES[2:], "latest"])


def test_prune_needs_keep(tmp_path, capsys):
    code, _, err = run_main(["runs", "--dir", str(tmp_path), "--prune"], capsys)
    assert code == 2 and "--keep" in err


def test_compare_outputs_are_listed_as_compares_not_incomplete_runs(tmp_path, capsys):
    """gantry-twin compare writes runs/compare/<UTC time>-<id>/ (compare.md, compare.json, plots/): a compare."""
    runs = _runs(tmp_path, NAMES[1])
    written, unfinished = runs / "compare" / NAMES[0], runs / "compare" / NAMES[1]
    (written / "plots").mkdir(parents=True)
    (written / "compare.md").write_text("| metric |\n")
    (written / "compare.json").write_text("{}")
    unfinished.mkdir()  # compare stopped before it wrote compare.json
    status = {(e.scenario, e.path.name): e.status for e in list_runs(runs)}
    assert status[("compare", NAMES[0])] == "compare" and status[("compare", NAMES[1])] == "incomplete"
    code, out, _ = run_main(["runs", "--dir", str(runs)], capsys)
    assert code == 0 and f"compare/{NAMES[0]}" in out and out.count("incomplete") == 2  # the run and the compare
    assert out.strip().splitlines()[-1].startswith("5 runs and 1 compare,")
