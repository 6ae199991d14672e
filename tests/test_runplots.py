"""The figures drawn with every run (gantry_twin.outputs.plots): what they read from the trace, and that a figure
never costs the run."""

from __future__ import annotations

import json

import numpy as np
import pyarrow.parquet as pq
import pytest

from gantry_twin.outputs import plots as runplots
from gantry_twin.outputs.plots import FIGURES, envelope, magnification, read_series

from .helpers import run_main

SHORT = ["--set", "duration_s=1", "--set", "window_s=[0.2, 1]", "--set", "estimates_window_s=[0.5, 1]", "--no-progress"]


@pytest.fixture(scope="module")
def strided_run(tmp_path_factory):
    """A 1 s DIARC run on the ellipse keeping one sample in 7 (figures read the rows the trace has)."""
    from gantry_twin.cli import app as cli

    out = tmp_path_factory.mktemp("plots") / "run"
    code = cli.main(["run", "no_load_ellipse", *SHORT, "--set", "outputs.trace_stride=7", "--out", str(out)])
    assert code == 0
    return out


def test_a_run_draws_every_figure_with_units(strided_run):
    names = sorted(p.name for p in (strided_run / "plots").iterdir())
    assert names == sorted(FIGURES)
    for name in names:
        assert (strided_run / "plots" / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_figure_labels_use_the_micro_sign_and_name_the_metric_window(strided_run):
    plt = runplots.pyplot()
    series = read_series(strided_run, _summary(strided_run), "r")
    fig = runplots.fig_eps_c(plt, [series])
    ax = fig.axes[0]
    assert ax.get_ylabel() == "contour error eps_c (µm)"
    assert any(t.startswith("metric window [0.20, 1.00] s") for t in ax.get_legend_handles_labels()[1])
    assert "µm" in runplots.fig_axial(plt, [series]).axes[0].get_ylabel()
    plt.close("all")


def test_commands_are_scaled_to_the_data_and_an_off_scale_limit_is_named(strided_run):
    plt = runplots.pyplot()
    series = read_series(strided_run, _summary(strided_run), "r")
    fig = runplots.fig_commands(plt, [series])
    for ax, (_, u) in zip(fig.axes, series.command, strict=True):
        low, high = ax.get_ylim()
        assert high < 10 and low > -10 and high - low < 4 * np.ptp(u)  # not squashed to +-10 V
        assert any("off the scale" in t.get_text() for t in ax.texts)
        # The label sits above the data (it hid u_y's first second on the circle).
        fig.canvas.draw()
        (text,) = ax.texts
        label_bottom = ax.transData.inverted().transform(text.get_window_extent().get_points())[0, 1]
        assert u.max() < label_bottom
    plt.close("all")


def test_untrusted_estimates_are_marked_in_their_panel(strided_run):
    summary = _summary(strided_run)
    untrusted = [n for n, e in (summary.estimates or {}).items() if e.trustworthy is False]
    assert untrusted  # a 1 s run vouches for few estimates
    plt = runplots.pyplot()
    fig = runplots.fig_estimates(plt, [read_series(strided_run, summary, "r")])
    titles = {ax.get_ylabel().split()[0]: ax.get_title() for ax in fig.axes}
    for name, title in titles.items():
        assert title.startswith("not trusted: ") == (name in untrusted), (name, title)
        if name in untrusted:  # the whole reason, its numbers included (cut at 85 characters, they were lost)
            assert title.replace("\n", " ") == summary.estimates[name].distrust
            assert all(len(line) <= runplots.DOUBT_CHARS for line in title.splitlines())
    plt.close("all")


def test_legends_are_outside_the_data(strided_run):
    # A legend in a corner of the axes hid the bracket program's spikes; "best" still covered estimates.
    plt = runplots.pyplot()
    series = read_series(strided_run, _summary(strided_run), "r")
    for draw in (runplots.fig_eps_c, runplots.fig_estimates, runplots.fig_contour):
        fig = draw(plt, [series])
        assert all(ax.get_legend() is None for ax in fig.axes), draw
        (legend,) = fig.legends
        boxes = [ax.get_window_extent() for ax in fig.axes]
        fig.canvas.draw()
        assert not any(legend.get_window_extent().overlaps(box) for box in boxes), draw
    fig = runplots.fig_axial(plt, [series, series])  # two runs: told apart by a legend, below the panels
    assert all(ax.get_legend() is None for ax in fig.axes) and len(fig.legends) == 1
    plt.close("all")


@pytest.mark.parametrize("fmt", ["svg", "pdf"])
def test_plot_format_and_dpi(strided_run, tmp_path, fmt):
    summary = _summary(strided_run)
    names = runplots.write_plots(strided_run, tmp_path / fmt, summary, fmt, 40)
    assert sorted(names) == sorted(n.replace(".png", f".{fmt}") for n in FIGURES)
    png = runplots.write_plots(strided_run, tmp_path / "png", summary, "png", 40)
    from PIL import Image

    assert Image.open(tmp_path / "png" / png[0]).info["dpi"][0] == pytest.approx(40, abs=1)


def _summary(run_dir):
    from gantry_twin.outputs.summary import RunSummary

    return RunSummary.model_validate_json((run_dir / "summary.json").read_text())


def test_binned_series_keep_the_peaks_and_times_of_the_trace(strided_run, monkeypatch):
    monkeypatch.setattr(runplots, "PLOT_BINS", 50)  # bins of many rows, and a shorter last one
    table = pq.read_table(strided_run / "trace.parquet")
    summary = json.loads((strided_run / "summary.json").read_text())
    series = read_series(strided_run, summary, "r")
    t = table.column("t_s").to_numpy()
    assert np.allclose(np.diff(t), 7 * 2e-4)  # the strided rows, their own times
    eps_um = table.column("eps_c_m").to_numpy() * 1e6
    bin_rows = -(-t.size // 50)  # rows per bin
    assert series.eps_c_um.size == -(-t.size // bin_rows) <= 50 and t.size % bin_rows  # a shorter last bin
    assert np.abs(series.eps_c_um).max() == np.abs(eps_um).max()  # the largest error survives binning
    k = np.argmax(np.abs(eps_um))
    assert t[k] in series.t_eps_s
    u_y = table.column("u_y_v").to_numpy()
    assert np.abs(series.command[1][1]).max() == np.abs(u_y).max()
    assert set(series.t_eps_s) <= set(t)
    # estimates: the first row of each bin, and the true theta (from the schema metadata) beside them
    assert series.theta_hat.shape == (series.eps_c_um.size, 8)
    assert np.array_equal(series.theta_hat[:, 0], table.column("theta_hat_M1").to_numpy()[::bin_rows])
    true = json.loads(table.schema.metadata[b"true_theta"])
    assert np.array_equal(series.true_theta[0], [true[n] for n in ("M1", "M2", "B1", "B2", "Af1", "Af2", "dN1", "dN2")])


def test_envelope_keeps_the_largest_magnitude_of_each_bin():
    t = np.arange(10.0)
    x = np.array([1.0, -5.0, 2.0, 0.5, 3.0, -0.1, 0.0, 0.0, -7.0, 1.0])
    tb, xb = envelope(t, x, 4)
    assert tb.tolist() == [1.0, 4.0, 8.0] and xb.tolist() == [-5.0, 3.0, -7.0]


def test_magnification_is_round_and_scales_the_error_to_the_path(strided_run):
    summary = json.loads((strided_run / "summary.json").read_text())
    series = read_series(strided_run, summary, "r")
    k = magnification([series])
    mantissa = k / 10 ** np.floor(np.log10(k))
    assert mantissa in (1.0, 2.0, 5.0)
    size = np.ptp(series.contour_m[:, :2], axis=0).max()
    share = k * np.abs(series.eps_c_um).max() * 1e-6 / size
    assert runplots.MAGNIFIED_SHARE / 5 < share <= runplots.MAGNIFIED_SHARE


def test_no_estimates_figure_for_a_controller_without_estimates(tmp_path, capsys):
    out = tmp_path / "drc"
    code, _, err = run_main(["run", "no_load_circle", *SHORT, "--controller", "drc", "--out", str(out)], capsys)
    assert code == 0, err
    assert sorted(p.name for p in (out / "plots").iterdir()) == sorted(set(FIGURES) - {"estimates.png"})


def test_a_figure_that_fails_does_not_cost_the_run(tmp_path, capsys, monkeypatch):
    out = tmp_path / "r"
    code, _, _ = run_main(["run", "no_load_circle", *SHORT, "--controller", "pd", "--out", str(out)], capsys)
    assert (out / "plots").is_dir()

    def broken(plt, runs):
        raise RuntimeError("injected drawing fault")

    monkeypatch.setitem(runplots.FIGURES, "contour.png", broken)
    code, stdout, err = run_main(["run", "no_load_circle", *SHORT, "--controller", "pd", "--out", str(out)], capsys)
    assert code == 0
    assert "gantry-twin: note: no plots: drawing them raised RuntimeError: injected drawing fault" in err
    assert sorted(p.name for p in out.iterdir()) == ["run_info.json", "scenario.yaml", "summary.json", "trace.parquet"]
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no half-drawn directory left
    assert stdout.strip().endswith("(summary.json, scenario.yaml, trace.parquet, run_info.json)")


def test_the_shaded_window_is_called_the_papers_only_when_it_is(tmp_path, capsys):
    out = tmp_path / "run"
    code, _, _ = run_main(
        ["run", "no_load_ellipse", "--set", "duration_s=5", "--no-progress", "--out", str(out)], capsys
    )
    assert code == 0
    summary = _summary(out)
    assert summary.contour_error_um.paper_window is True
    plt = runplots.pyplot()
    labels = runplots.fig_eps_c(plt, [read_series(out, summary, "r")]).axes[0].get_legend_handles_labels()[1]
    assert any(t.startswith("paper's window (second period) [") for t in labels)
    plt.close("all")
