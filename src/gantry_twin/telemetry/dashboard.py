"""The dashboard's layout (a rerun blueprint) and the gantry drawn in 3D from the compiled MJCF model.

Nothing here logs: :mod:`gantry_twin.telemetry.observer` sends what these describe.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from gantry_twin.paths.contours import contour_error
from gantry_twin.plant.model import Plant

#: Default magnification of the contour error in the XY view (1 um drawn as 10 mm).
ERROR_MAGNIFICATION = 10_000.0
#: The same for a part program's run: its errors at corners are tens of um (a 10 um error drawn as 10 mm; at
#: 10 000x the bracket's corners were drawn a metre off its 400 mm part). During a rapid (G0) move, not part of
#: the part, the actual position is drawn unmagnified.
PROGRAM_ERROR_MAGNIFICATION = 1_000.0
#: The estimates' verdicts after a run: a Markdown list of those not trusted, each with its reason.
VERDICTS_ENTITY = "estimates/verdicts"
#: The timeline every sample is logged on (a duration from the start of the run).
TIMELINE = "sim_time"
#: Margin added on each side of what a ranged plot must show, as a fraction of its span.
RANGE_MARGIN = 0.1
#: Most labelled ticks in a ranged plot: the viewer labels only ticks at powers of ten spaced about 20 px or more
#: apart, so a small plot (an estimate, about 130 px tall) shows at most this many labels.
RANGE_MAX_LABELS = 6


# ---------------------------------------------------------------------------------------------
# The gantry in 3D, read from the compiled MJCF model


@dataclass(frozen=True)
class BodyBoxes:
    """One body of the model drawn as its box geoms, in the body's own frame (metres).

    ``entity``: path under ``gantry/`` following the body tree. The body sits at
    ``offset_m`` (rotation ``quat_xyzw``) in its parent's frame, shifted by
    ``q[:, axis] * direction`` for each slide joint ``(axis, direction)``;
    ``axis`` indexes the trace's q (0 = X, 1 = Y).
    """

    entity: str
    offset_m: np.ndarray
    quat_xyzw: np.ndarray
    slides: tuple[tuple[int, np.ndarray], ...]
    half_sizes_m: np.ndarray
    centers_m: np.ndarray
    quats_xyzw: np.ndarray
    colors_rgba: np.ndarray

    def translations_m(self, q_m: np.ndarray) -> np.ndarray:
        """(N, 3) position of the body frame in its parent's frame for joint positions q (N, 2)."""
        q = np.atleast_2d(q_m)
        out = np.tile(self.offset_m, (q.shape[0], 1))
        for axis, direction in self.slides:
            out += q[:, axis : axis + 1] * direction
        return out


def _xyzw(quat_wxyz: np.ndarray) -> np.ndarray:
    w, x, y, z = np.asarray(quat_wxyz, dtype=float)
    return np.array([x, y, z, w])


def gantry_bodies(plant: Plant) -> list[BodyBoxes]:
    """Every body below the world that has box geoms or children, parents first."""
    m = plant.model
    axis_of_qpos = {int(adr): i for i, adr in enumerate(plant.qpos_index)}
    paths: dict[int, str] = {0: "gantry"}
    bodies: list[BodyBoxes] = []
    for b in range(1, m.nbody):
        name = m.body(b).name or f"body{b}"
        paths[b] = f"{paths[int(m.body_parentid[b])]}/{rr.escape_entity_path_part(name)}"
        rotation = np.zeros(9)
        mujoco.mju_quat2Mat(rotation, m.body_quat[b])
        slides = []
        for j in range(int(m.body_jntadr[b]), int(m.body_jntadr[b]) + int(m.body_jntnum[b])):
            if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_SLIDE and int(m.jnt_qposadr[j]) in axis_of_qpos:
                slides.append((axis_of_qpos[int(m.jnt_qposadr[j])], rotation.reshape(3, 3) @ m.jnt_axis[j]))
        geoms = [g for g in range(m.ngeom) if m.geom_bodyid[g] == b and m.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX]
        bodies.append(
            BodyBoxes(
                entity=paths[b],
                offset_m=m.body_pos[b].copy(),
                quat_xyzw=_xyzw(m.body_quat[b]),
                slides=tuple(slides),
                half_sizes_m=m.geom_size[geoms].copy(),
                centers_m=m.geom_pos[geoms].copy(),
                quats_xyzw=np.array([_xyzw(m.geom_quat[g]) for g in geoms]).reshape(-1, 4),
                colors_rgba=np.clip(np.rint(m.geom_rgba[geoms] * 255), 0, 255).astype(np.uint8),
            )
        )
    return bodies


def magnified_contour_m(path, q_m: np.ndarray, phi_guess: np.ndarray, factor: float) -> np.ndarray:
    """Points p + factor (q - p), p the closest point of ``path`` to each q (N, 2), metres."""
    _, phi_closest = contour_error(path, q_m, phi_guess)
    closest = path.derivatives(phi_closest)[0]
    return closest + factor * (np.asarray(q_m) - closest)


# ---------------------------------------------------------------------------------------------
# The dashboard


def plot_range(lo: float, hi: float, margin: float = RANGE_MARGIN) -> tuple[float, float]:
    """A y range showing [lo, hi] with ``margin`` of its span on each side, and at least two labelled ticks.

    The viewer labels ticks at multiples of a power of ten d, and only when
    they are far enough apart (an automatic range of a small signal can
    show a single "0"), and not at the very edge. Here d is the smallest power
    of ten with at most :data:`RANGE_MAX_LABELS` multiples in the range, the
    ends are multiples of d / 10, widened until two multiples of d lie at
    least d / 10 inside. A constant (lo == hi) gets a span of 10 % of its size (1 if 0).
    """
    span = hi - lo
    if not span > 0:
        span = 0.1 * abs(hi) or 1.0
        lo, hi = lo - span / 2, hi + span / 2
    lo, hi = lo - margin * span, hi + margin * span
    fine = 10.0 ** math.floor(math.log10(hi - lo) - 1)
    while True:  # in units of fine: ticks every 10
        a, b = math.floor(lo / fine), math.ceil(hi / fine)
        if (b - 1) // 10 - -((a + 1) // -10) + 1 <= RANGE_MAX_LABELS:
            break
        fine *= 10.0
    while (b - 1) // 10 - -((a + 1) // -10) + 1 < 2:  # ticks at least one fine step inside the ends
        b = 10 * ((b - 1) // 10 + 1) + 1
        if (b - 1) // 10 - -((a + 1) // -10) + 1 < 2:
            a = 10 * (-((a + 1) // -10) - 1) - 1
    return a * fine, b * fine


def panel_name(name: str, unit: str) -> str:
    """A plot's title with its unit in brackets: ``Inputs [V]``."""
    return f"{name} [{unit}]"


def dashboard_blueprint(
    estimate_entities: Sequence[str] = (),
    magnification: float = ERROR_MAGNIFICATION,
    desired_mm: np.ndarray | None = None,
    health: bool = False,
    ranges: Mapping[str, tuple[float, float]] | None = None,
    titles: Mapping[str, str] | None = None,
    verdicts: bool = False,
) -> rrb.Blueprint:
    """Default layout: contour and 3D | errors and inputs | one plot per estimate (if any).

    ``health``: add the health monitor's excitation plot and alarm log to the middle column.
    ``verdicts``: add the estimates' verdicts (``estimates/verdicts``, which are not trusted and why) below the
    3D view.

    The XY view shows every strip of the actual contour up to the time cursor
    (visible range from -infinity); ``desired_mm`` (N, 2) sets its bounds.
    ``ranges``: the y range of a time-series plot by its origin (others scale
    to their data; zooming stays free); ``titles``: an estimate plot's title
    by its origin (default: the entity's name).
    """
    ranges = ranges or {}
    titles = titles or {}

    def series(origin: str, name: str) -> rrb.TimeSeriesView:
        axis = rrb.ScalarAxis(range=ranges[origin], zoom_lock=False) if origin in ranges else None
        return rrb.TimeSeriesView(origin=origin, name=name, axis_y=axis)

    history = rrb.VisibleTimeRange(
        TIMELINE, start=rr.TimeRangeBoundary.infinite(), end=rr.TimeRangeBoundary.cursor_relative()
    )
    bounds = None
    if desired_mm is not None and len(desired_mm):
        lo, hi = np.min(desired_mm, axis=0), np.max(desired_mm, axis=0)
        margin = 0.15 * float(np.max(hi - lo)) + 1.0
        # contour_mm/xy flips y (2D views draw y downwards), so the view's y range is mirrored.
        bounds = rrb.VisualBounds2D(
            x_range=[lo[0] - margin, hi[0] + margin], y_range=[-hi[1] - margin, -lo[1] + margin]
        )
    left_views: list = [
        rrb.Spatial2DView(
            origin="contour_mm",
            name=f"{panel_name('XY contour', 'mm')}, error x{magnification:g}",
            time_ranges=[history],
            visual_bounds=bounds,
        ),
        rrb.Spatial3DView(
            origin="gantry",
            name=panel_name("Gantry 3D", "m"),
            eye_controls=rrb.EyeControls3D(position=[0.9, -1.3, 0.9], look_target=[0.0, 0.0, -0.08]),
        ),
    ]
    if verdicts:
        left_views.append(rrb.TextDocumentView(origin=VERDICTS_ENTITY, name="Estimates not trusted, and why"))
    left = rrb.Vertical(*left_views, row_shares=[1.6, 1.0, 1.0][: len(left_views)])
    middle_views = [
        series("errors/contour", panel_name("Contour error", "µm")),
        series("errors/axial", panel_name("Axial errors", "µm")),
        series("inputs", panel_name("Inputs", "V")),
    ]
    if health:
        middle_views += [
            series("health/excitation_V", panel_name("Excitation per axis", "V")),
            series("health/trustworthy", panel_name("Trustworthy estimates (1 = yes)", "-")),
            rrb.TextLogView(origin="health/alarms", name="Health alarms"),
        ]
    middle = rrb.Vertical(*middle_views)
    columns: list = [left, middle]
    if estimate_entities:
        views = [series(e, titles.get(e, e.removeprefix("estimates/"))) for e in estimate_entities]
        columns.append(rrb.Grid(*views, grid_columns=2, name="Estimates"))
    shares = [1.0, 1.0, 1.2][: len(columns)]
    return rrb.Blueprint(
        rrb.Horizontal(*columns, column_shares=shares),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="collapsed"),
    )
