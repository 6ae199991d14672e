"""One signed-percentage format for every report and summary (gantry_twin.settings.signed_pct): never "-0.0 %"."""

from __future__ import annotations

import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from gantry_twin.outputs.summary import Estimate
from gantry_twin.reports import compare, rig
from gantry_twin.reports.paper import PAPER_CONTOUR_UM, Case, CaseResult
from gantry_twin.settings import signed_pct

SRC = Path(__file__).resolve().parents[1] / "src" / "gantry_twin"


@pytest.mark.parametrize(
    ("x", "decimals", "text"),
    [
        (-0.04, 1, "0.0 %"),
        (0.04, 1, "0.0 %"),
        (-0.0, 1, "0.0 %"),
        (-0.06, 1, "-0.1 %"),
        (2.0, 1, "+2.0 %"),
        (-0.004, 2, "0.00 %"),
        (-0.4, 0, "0 %"),
        (-0.6, 0, "-1 %"),
        (float("nan"), 1, "-"),
        (None, 1, "-"),
    ],
)
def test_signed_pct(x, decimals, text):
    assert signed_pct(x, decimals) == text


def test_a_column_pads_the_number():
    assert signed_pct(-0.001, 2, width=7) == "   0.00 %" and signed_pct(None, 2, width=7) == "      -"


def test_no_module_formats_a_signed_percentage_itself():
    """A ``{x:+.Nf} %`` format anywhere but settings.signed_pct could print "-0.0 %" again."""
    pattern = re.compile(r"\{[^{}]*:\+\d*\.\d+f\}\s*%")
    offenders = [
        f"{path.relative_to(SRC)}:{n}"
        for path in SRC.rglob("*.py")
        if path.name != "settings.py"
        for n, line in enumerate(path.read_text().splitlines(), 1)
        if pattern.search(line)
    ]
    assert offenders == []


def _result(contour: str, set_id: int, label: str, rms: float, mx: float) -> CaseResult:
    case = Case(set_id, contour, label, "x.yaml", "diarc", ())
    return CaseResult(case, rms, mx, (0.0, 1.0), 1, 0.0, [0.0] * 8, None, (0.0, 1.0), np.zeros(1), np.zeros(1))


def test_the_rig_report_never_prints_minus_zero():
    paper = PAPER_CONTOUR_UM[("circle", 1, "C1")]
    just_under = _result("circle", 1, "C1", paper[0] * 0.998, paper[1] * 0.996)  # -0.2 %, -0.4 %: rounds to 0
    key = ("circle", 1, "C1")
    rows = rig.matrix_table({(1, "circle", "C1"): just_under}, {(1, "circle", "C1"): just_under})
    row = next(r for r in rows if r.startswith(f"| {key[0]} | {key[1]} | {key[2]} |"))
    assert "| 0 / 0 |" in row and "-0" not in row


def test_compare_never_prints_minus_zero_and_marks_an_untrusted_estimate():
    summary = SimpleNamespace(  # the estimates section of a summary is all _estimate reads
        estimates={
            "M1": Estimate(estimate=0.12, true=0.12, error_pct=-0.001, trustworthy=True),
            "B1": Estimate(estimate=0.4, true=0.5, error_pct=-20.0, trustworthy=False, why="not excited"),
        }
    )
    assert compare._estimate(summary, "M1") == "0.12000 / 0.1200 (0.00 %)"
    assert compare._estimate(summary, "B1") == "0.40000 / 0.5000 (-20.00 %); not trusted: not excited"
    assert Estimate(estimate=1.0, trustworthy=False, why="x").distrust == "not trusted: x"
