"""Finding scenarios and controllers from the command line: the listing, "did you mean", --help, short names."""

from __future__ import annotations

import pytest

from gantry_twin.controllers import PD, register, unregister
from gantry_twin.scenario import ScenarioError, display_source, load_scenario, shipped, shipped_scenarios
from gantry_twin.scenario.listing import describe

from .helpers import run_main


def test_scenarios_lists_every_shipped_scenario_on_one_line(capsys):
    code, out, err = run_main(["scenarios"], capsys)
    assert code == 0 and err == ""
    lines = out.strip().splitlines()
    assert [line.split()[0] for line in lines] == [p.stem for p in shipped_scenarios()]
    by_name = dict(line.split(maxsplit=1) for line in lines)
    assert by_name["no_load_circle"] == f"{load_scenario(shipped('no_load_circle')).description} (30 s)"


def test_a_scenario_without_a_description_is_described_by_its_contour_payload_and_duration(tmp_path):
    path = tmp_path / "mine.yaml"
    path.write_text("contour: {type: ellipse}\npayload: {mass_kg: 2.5}\nduration_s: 12\n")
    assert describe(path) == "ellipse, payload 2.5 kg (12 s)"


def test_a_near_miss_name_gets_did_you_mean(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for command in ("run", "monitor", "validate"):
        code, out, err = run_main([command, "no_load_circl"], capsys)
        assert code == 2 and out == ""
        assert err == (
            "gantry-twin: error: no such scenario file or shipped scenario 'no_load_circl'; "
            "did you mean 'no_load_circle'?\n"
        )


def test_help_lists_the_controllers_registered_plug_ins_included(capsys):
    register("my_plug_in", PD)
    try:
        for command in ("run", "monitor", "validate"):
            code, out, _ = run_main([command, "--help"], capsys)
            assert code == 0
            text = " ".join(out.split()).replace("gantry- twin", "gantry-twin")  # argparse wraps the help
            assert "instead of the scenario's: darc, diarc, drc, fmu, my_plug_in, pd" in text
            assert command == "validate" or "gantry-twin scenarios lists them" in text
    finally:
        unregister("my_plug_in")


@pytest.mark.parametrize("command", ["run", "validate"])
def test_errors_name_a_shipped_scenario_by_its_name(capsys, command):
    code, _, err = run_main([command, "no_load_circle", "--set", "payload.mass_kg=-2"], capsys)
    assert code == 2
    assert err.startswith("gantry-twin: error: no_load_circle: payload.mass_kg: ")
    assert str(shipped("no_load_circle").parent) not in err


def test_display_source_shortens_only_shipped_files(tmp_path):
    assert display_source(shipped("load_5kg_circle")) == "load_5kg_circle"
    own = tmp_path / "load_5kg_circle.yaml"  # the same name elsewhere is the user's file: its path
    assert display_source(own) == str(own)
    assert str(ScenarioError(str(own), "duration_s", "bad")) == f"{own}: duration_s: bad"
