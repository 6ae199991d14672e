"""trace.parquet's storage (gantry_twin.outputs.tracefile): float64 time and positions, float32 the rest, zstd.

The figures a user computes from the written trace (contour error rms/max, mean estimates, axial
errors from the positions) against the same figures computed from the run in memory.
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from gantry_twin.outputs.tracefile import FLOAT64_COLUMNS, TRACE_COLUMNS
from gantry_twin.plant.model import THETA_NAMES
from gantry_twin.run import execute, write_run
from gantry_twin.scenario import build, load_scenario, shipped

from .helpers import FLOAT32_REL, trace_column

WINDOW_S = (0.2, 1.0)
#: A DIARC run with a payload picked up (so true theta moves and is a column too).
OVERRIDES = [
    "duration_s=1.0",
    f"window_s=[{WINDOW_S[0]}, {WINDOW_S[1]}]",
    "estimates_window_s=[0.5, 1.0]",
    "changes={payload_change: [{time_s: 0.4, mass_kg: 3.0}]}",
]


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """(the run's trace in memory, its trace.parquet read back)."""
    built = build(load_scenario(shipped("no_load_circle"), OVERRIDES))
    trace = execute(built)
    out = tmp_path_factory.mktemp("trace") / "run"
    write_run(out, built, trace, 0.0)
    return trace, pq.read_table(out / "trace.parquet"), out / "trace.parquet"


def test_time_and_positions_are_float64_and_every_other_column_float32(written):
    _, table, _ = written
    assert set(FLOAT64_COLUMNS) == {"t_s", "x_m", "y_m", "x_meas_m", "y_meas_m", "x_d_m", "y_d_m"}
    for field in table.schema:
        assert field.type == (pa.float64() if field.name in FLOAT64_COLUMNS else pa.float32()), field.name
    assert {"theta_hat_M1", "gamma_lambda_max", "true_theta_M1", "eps_c_m", "u_x_v"} <= set(table.column_names)


def test_time_and_positions_are_written_bit_for_bit(written):
    trace, table, _ = written
    for name, (attribute, column) in TRACE_COLUMNS.items():
        if name in FLOAT64_COLUMNS:
            values = getattr(trace, attribute)
            values = values if column is None else values[:, column]
            np.testing.assert_array_equal(table.column(name).to_numpy(), values, err_msg=name)


def test_axial_errors_from_the_written_positions_are_those_of_the_run(written):
    """q - q_d from the file's positions is the run's e to the last bit of its float64 subtraction
    (float32 positions would be 15 nm off at 0.25 m)."""
    trace, table, _ = written
    for i, axis in enumerate("xy"):
        e_m = trace_column(table, f"{axis}_m") - trace_column(table, f"{axis}_d_m")
        np.testing.assert_allclose(e_m, trace.e_m[:, i], rtol=0, atol=1e-15, err_msg=axis)
        np.testing.assert_allclose(trace_column(table, f"e_{axis}_m"), e_m, rtol=2 * FLOAT32_REL, atol=0)


def test_figures_from_the_written_trace_match_the_run_to_float32_rounding(written):
    """Contour error rms and max over the window, mean estimates and true theta: within 2**-23 relative."""
    trace, table, _ = written
    t = table.column("t_s").to_numpy()
    in_window = (t >= WINDOW_S[0]) & (t < WINDOW_S[1])
    assert in_window.sum() == 4000

    def rms_max_um(eps_c_m: np.ndarray) -> tuple[float, float]:
        eps_um = np.abs(eps_c_m[in_window]) * 1e6
        return float(np.sqrt(np.mean(eps_um**2))), float(eps_um.max())

    from_file, in_memory = rms_max_um(trace_column(table, "eps_c_m")), rms_max_um(trace.eps_c_m)
    assert from_file == pytest.approx(in_memory, rel=2 * FLOAT32_REL)
    for i, name in enumerate(THETA_NAMES):
        for column, series in (("theta_hat", trace.controller_state["theta_hat"]), ("true_theta", trace.true_theta_t)):
            values = series[in_window, i]
            tolerance = 2 * FLOAT32_REL * np.abs(values).mean()  # the mean of values each rounded by 2**-24
            mean_from_file = trace_column(table, f"{column}_{name}")[in_window].mean()
            assert abs(mean_from_file - values.mean()) <= tolerance, (column, name)


def test_the_trace_is_compressed(written):
    """zstd and BYTE_STREAM_SPLIT: under 40 % of 8 bytes a value (93 % before; docs/performance.md)."""
    _, table, path = written
    metadata = pq.ParquetFile(path).metadata
    assert metadata.row_group(0).column(0).compression == "ZSTD"
    assert "BYTE_STREAM_SPLIT" in metadata.row_group(0).column(1).encodings
    assert path.stat().st_size <= 0.4 * table.num_rows * table.num_columns * 8
