"""Sweep figures (gantry_twin.sweep.plots): a categorical axis is drawn as categories, a numeric one as a line."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

from gantry_twin.sweep import plan_sweep  # noqa: E402
from gantry_twin.sweep import plots as sweep_plots  # noqa: E402
from gantry_twin.sweep.spec import parse_sweep  # noqa: E402

TEXT = """\
scenario: no_load_circle
set: {duration_s: 2, window_s: [0.5, 2], estimates_window_s: [1, 2]}
axes:
  - {field: payload.mass_kg, values: [0, 2.5, 5]}
  - {field: controller.name, values: [diarc, darc, drc]}
"""


def _drawn(monkeypatch, tmp_path, field):
    plan = plan_sweep(parse_sweep(TEXT, "s.yaml"), "s.yaml")
    rows = [
        {"payload.mass_kg": m, "controller.name": c, "contour_rms_um": 1.0 + m + i}
        for m in (0, 2.5, 5)
        for i, c in enumerate(("diarc", "darc", "drc"))
    ]
    figures = []
    monkeypatch.setattr(sweep_plots, "_save", lambda fig, path: figures.append(fig))
    assert sweep_plots.metric_plot(plan, rows, field, "contour_rms_um", tmp_path) is not None
    return figures[0].axes[0]


def test_a_categorical_axis_has_no_line_between_categories(monkeypatch, tmp_path):
    ax = _drawn(monkeypatch, tmp_path, "controller.name")
    assert [t.get_text() for t in ax.get_xticklabels()] == ["diarc", "darc", "drc"]
    for line in ax.get_lines():
        assert line.get_linestyle() == "None", line.get_label()


def test_a_numeric_axis_joins_its_means(monkeypatch, tmp_path):
    ax = _drawn(monkeypatch, tmp_path, "payload.mass_kg")
    assert any(line.get_linestyle() == "-" and len(line.get_xdata()) == 3 for line in ax.get_lines())


def test_untrusted_estimates_are_drawn_hollow_and_counted(monkeypatch, tmp_path):
    """A DIARC point whose estimate the confidence tests did not trust (trustworthy_B1 false) is a hollow dot."""
    plan = plan_sweep(parse_sweep(TEXT, "s.yaml"), "s.yaml")
    rows = [
        {"payload.mass_kg": m, "controller.name": "diarc", "error_pct_B1": 2.0 * m, "trustworthy_B1": m != 5}
        for m in (0, 2.5, 5)
    ]
    figures = []
    monkeypatch.setattr(sweep_plots, "_save", lambda fig, path: figures.append(fig))
    for metric in ("error_pct_B1", "contour_rms_um"):
        for r in rows:
            r["contour_rms_um"] = 1.0
        assert sweep_plots.metric_plot(plan, rows, "payload.mass_kg", metric, tmp_path) is not None
    error, other = (fig.axes[0] for fig in figures)
    hollow = [line for line in error.get_lines() if line.get_markerfacecolor() == "none"]
    assert len(hollow) == 1 and list(hollow[0].get_xdata()) == [5.0] and list(hollow[0].get_ydata()) == [10.0]
    assert "(3 points, 1 not trusted: hollow)" in error.get_title()
    assert not any(line.get_markerfacecolor() == "none" for line in other.get_lines())  # not an estimate's metric
    assert "not trusted" not in other.get_title()
