"""Run directories that never overwrite and the ``latest`` pointer (gantry_twin.outputs.rundirs)."""

from __future__ import annotations

import os
import re

from gantry_twin.outputs import rundirs
from gantry_twin.outputs.rundirs import LATEST, new_run_dir, point_latest, resolve_run


def test_run_dir_names_sort_by_time_and_differ_within_a_second(tmp_path):
    early = new_run_dir(tmp_path, now_s=1_796_000_000.0)
    late = new_run_dir(tmp_path, now_s=1_796_000_001.0)
    assert re.fullmatch(r"\d{8}T\d{6}Z-[0-9a-f]{6}", early.name), early.name
    assert early.name.startswith("20261130T") and early.parent == tmp_path
    assert sorted([late.name, early.name]) == [early.name, late.name]
    same_second = {new_run_dir(tmp_path, now_s=1_796_000_000.0).name for _ in range(50)}
    assert len(same_second) == 50
    assert not early.exists()  # named, not made: the run's writer makes it


def test_a_taken_name_is_not_given_again(tmp_path, monkeypatch):
    ids = iter(["aaaaaa", "aaaaaa", "bbbbbb"])
    monkeypatch.setattr(rundirs.secrets, "token_hex", lambda n: next(ids))
    first = new_run_dir(tmp_path, now_s=0.0)
    first.mkdir()
    assert new_run_dir(tmp_path, now_s=0.0).name == "19700101T000000Z-bbbbbb"


def test_latest_is_a_relative_link_replaced_in_place(tmp_path):
    a, b = tmp_path / "runs" / "x" / "a", tmp_path / "runs" / "x" / "b"
    a.mkdir(parents=True)
    b.mkdir()
    latest = point_latest(a)
    assert latest == a.parent / LATEST and os.readlink(latest) == "a"
    point_latest(b)
    assert os.readlink(latest) == "b"  # relative: the runs/ tree can be moved
    assert resolve_run(latest).resolve() == b.resolve()
    assert sorted(p.name for p in a.parent.iterdir()) == ["a", "b", "latest"]  # no temporary link left


def test_without_symbolic_links_latest_is_a_text_file(tmp_path, monkeypatch):
    run = tmp_path / "x" / "20261201T000000Z-abcdef"
    run.mkdir(parents=True)
    (run / "summary.json").write_text("{}")

    def no_links(*args, **kwargs):
        raise OSError("symbolic links are not supported here")

    monkeypatch.setattr(rundirs.os, "symlink", no_links)
    latest = point_latest(run)
    assert not latest.is_symlink() and latest.read_text() == run.name + "\n"
    assert resolve_run(latest) == run
    assert resolve_run(tmp_path / "x") == run  # runs/<name>: its latest
    assert resolve_run(run) == run
