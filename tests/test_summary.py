"""summary.json through its one type (gantry_twin.outputs.summary.RunSummary): written, read back, refused."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from gantry_twin.outputs.summary import RunSummary, SummaryError, summary_json
from gantry_twin.run import run_and_write
from gantry_twin.scenario import build, load_scenario, shipped

DOCS = Path(__file__).resolve().parents[1] / "docs" / "cli.md"


@pytest.fixture(scope="module")
def written(tmp_path_factory) -> tuple[Path, RunSummary]:
    out = tmp_path_factory.mktemp("run")
    path = shipped("no_load_circle")
    built = build(load_scenario(path, ["duration_s=0.6", "window_s=[0.1, 0.6]", "estimates_window_s=[0.1, 0.6]"]))
    outcome = run_and_write(out, built)
    return out / "summary.json", outcome.summary


def test_a_written_summary_reads_back_as_the_same_type(written):
    path, summary = written
    again = RunSummary.read(path)
    assert again == summary
    assert summary_json(again) == path.read_text()  # the same bytes: the type is the format
    assert again.estimates["M1"].trustworthy is not None  # DIARC's verdicts survive the round trip


@pytest.mark.parametrize(
    ("change", "said"),
    [
        (lambda d: d.update(surprise=1), "surprise: unknown key"),
        (lambda d: d.pop("steps"), "steps: required field is missing"),
        (lambda d: d["contour_error_um"].update(rms="big"), "contour_error_um.rms"),
        (lambda d: d["estimates"]["M1"].update(extra=0.0), "estimates.M1.extra: unknown key"),
        (lambda d: d.update(schema_version=99), "schema_version"),
    ],
)
def test_an_unknown_missing_or_mistyped_key_is_refused_by_name(written, tmp_path, change, said):
    path, _ = written
    data = json.loads(path.read_text())
    change(data)
    bad = tmp_path / "summary.json"
    bad.write_text(json.dumps(data))
    with pytest.raises(SummaryError) as caught:
        RunSummary.read(bad)
    assert said in str(caught.value) and "\n" not in str(caught.value)


def test_the_documented_keys_are_the_type_s_fields_in_order():
    text = DOCS.read_text(encoding="utf-8")
    section = text.split("### `summary.json`", 1)[1].split("\n### ", 1)[0]
    documented = re.findall(r"^\| `([a-z_]+)` \|", section, flags=re.M)
    assert documented == list(RunSummary.model_fields)
