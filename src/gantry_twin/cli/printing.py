"""What the command line prints of a run: the short summary, the health lines, the whole-run figures."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from gantry_twin.health.monitor import Alarm
from gantry_twin.loop.events import END_STOP, SATURATION_WARNING_FRACTION
from gantry_twin.outputs.plots import run_label
from gantry_twin.outputs.summary import Estimate, Health, RunSummary
from gantry_twin.plant.model import AXES
from gantry_twin.settings import signed_pct

#: The printed summary lists the rms of each period when the run has at most this many (else the first and last).
PERIODS_PRINTED = 12


def format_summary(summary: RunSummary, wall_time_s: float, out: Path | None = None, files: Sequence[str] = ()) -> str:
    """The short human summary ``run`` prints (``files``: those written into ``out``)."""
    c = summary.contour_error_um
    lines = [f"{run_label(summary)}: {summary.duration_s:g} s simulated ({summary.steps} steps) in {wall_time_s:.1f} s"]
    if c is not None:
        lines.append(
            f"contour error eps_c over [{c.window_s[0]:.3f}, {c.window_s[1]:.3f}] s (window_s"
            + ("; rapid moves left out" if summary.part_error is not None else "")
            + f"): rms {c.rms:.3f} um, max {c.max:.3f} um"
        )
    lines += whole_run_lines(summary)
    if summary.estimates is not None and summary.estimates_window_s is not None:
        w = summary.estimates_window_s
        lines.append(f"estimates (mean over [{w[0]:.3f}, {w[1]:.3f}] s)  estimate     true    error")
        for name, e in summary.estimates.items():
            lines.append(f"  {name:<4} {e.estimate:12.5f} {_true(e)}  {_pct(e)}{trust_mark(e)}")
    if summary.part_error is not None:
        lines.extend(format_part(summary))
    if summary.health is not None:
        lines.extend(format_health(summary.health))
    if out is not None:
        lines.append(f"results in {out}/" + (f" ({', '.join(files)})" if files else ""))
    return "\n".join(lines)


def format_part(summary: RunSummary) -> list[str]:
    """A part program's error to its programmed lines and arcs, and its worst corner."""
    p = summary.part_error
    lines = [
        f"part error (to the programmed lines and arcs): max {p.max_um:.3f} um, rms {p.rms_um:.3f} um over "
        f"{p.blocks} blocks and {p.corners} corners; cycle time {p.cycle_time_s:.3f} s, "
        f"feed achieved {1e3 * p.feed_achieved_m_s:.1f} mm/s"
    ]
    if p.worst_corners:
        c = p.worst_corners[0]
        lines.append(
            f"  worst corner: line {c.line} ({c.kind}, turn {c.turn_rad * 57.29577951308232:.0f} deg) "
            f"max {c.max_um:.3f} um at {1e3 * c.speed_m_s:.1f} mm/s, t = {c.time_s:.3f} s"
        )
    if p.dropped or p.merged:
        dropped = ", ".join(f"{kind} {n}" for kind, n in sorted(p.dropped.items())) or "nothing"
        lines.append(f"  dropped: {dropped}; merged (G64 Q): {p.merged} G1 line(s)")
    lines += [f"  {message}" for message in p.messages]
    return lines


def _true(e: Estimate) -> str:
    return "       -" if e.true is None else f"{e.true:8.4f}"


def _pct(e: Estimate) -> str:
    return signed_pct(e.error_pct, 2, width=7)


def trust_mark(e: Estimate) -> str:
    """``  (not trusted: why)`` after an estimate the run's own signals cannot vouch for; empty otherwise."""
    return f"  ({e.distrust})" if e.distrust else ""


def format_health(health: Health) -> list[str]:
    """The health monitor's alarms and per-parameter status, for the printed summary."""
    alarms = health.alarms
    lines = [
        f"health: {len(alarms)} alarm{'' if len(alarms) == 1 else 's'}"
        + (f" (baseline: {health.baseline['source']})" if health.baseline is not None else "")
    ]
    for a in alarms:  # summary.json's alarms hold exactly an Alarm's fields
        cleared = "" if a.cleared_s is None else f", cleared at {a.cleared_s:.2f} s"
        lines.append(f"  ALARM {Alarm(**a.model_dump()).describe()}{cleared}")
    if health.status:
        lines.append("  status at the end: " + ", ".join(f"{n} {s}" for n, s in health.status.items()))
    ex = ", ".join(
        f"{axis} {e.level_v_final:.3g} V" for axis, e in health.excitation.items() if e.level_v_final is not None
    )
    if ex:
        lines.append(f"  excitation level at the end (sqrt lambda_min, eq. 29): {ex}")
    return lines


def whole_run_lines(summary: RunSummary) -> list[str]:
    """The printed lines of summary.json's whole-run figures, each with its window."""
    whole, periods = summary.whole_run, summary.contour_error_per_period_um
    lines = []
    if whole is not None:
        (a, b), (ca, cb) = whole.window_s, whole.command_window_s
        c, e, u = whole.contour_error_um, whole.axial_error_rms_um, whole.max_abs_command_v
        lines += [
            f"contour error eps_c over [{a:.3f}, {b:.3f}] s (whole run from the start of window_s): "
            f"rms {c.rms:.3f} um, max {c.max:.3f} um",
            f"axial error e over [{a:.3f}, {b:.3f}] s: rms " + ", ".join(f"{k} {v:.3f} um" for k, v in e.items()),
            f"command u over [{ca:.3f}, {cb:.3f}] s: max |u| " + ", ".join(f"{k} {v:.3f} V" for k, v in u.items()),
        ]
        if summary.saturation:
            lines[-1] += "; at the limit " + ", ".join(
                f"{k} {100 * s.fraction:.2f} %" for k, s in summary.saturation.items()
            )
    if periods is not None and periods.rms:
        rms = periods.rms
        shown = " ".join(f"{v:.3f}" for v in rms)
        if len(rms) > PERIODS_PRINTED:
            half = PERIODS_PRINTED // 2
            shown = " ".join(f"{v:.3f}" for v in rms[:half]) + " ... " + " ".join(f"{v:.3f}" for v in rms[-half:])
        lines.append(
            f"rms eps_c per period of {periods.period_s:.3f} s from {periods.start_s:.3f} s "
            f"({len(rms)} period{'' if len(rms) == 1 else 's'}, the last up to the end): {shown} um"
        )
    return lines


def touched_end_stop(summary: RunSummary) -> bool:
    """True if the run's summary records an end-stop contact (what ``--strict`` refuses)."""
    return any((summary.end_stop_contacts or {}).values())


def travel_warnings(summary: RunSummary) -> list[str]:
    """One line per axis that touched an end stop or whose command saturated above the warning level."""
    lines = []
    contacts = summary.end_stop_contacts or {}
    for axis in AXES:
        n = contacts.get(axis, 0)
        if not n:
            continue
        listed = [e for e in summary.events or [] if e.kind == END_STOP and e.axis == axis]
        where = ""
        if listed:
            first, furthest = listed[0], max(listed, key=lambda e: abs(e.position_m))
            where = f" ({first.end_m:+.3f} m) at t = {first.t_s:.4f} s, furthest at {furthest.position_m:+.5f} m"
        lines.append(
            f"end stop: the {axis.upper()} carriage reached its travel end{where} ({n} contact{'' if n == 1 else 's'})"
        )
    for axis, s in (summary.saturation or {}).items():
        if s.fraction > SATURATION_WARNING_FRACTION:
            lo, hi = s.limit_v
            lines.append(
                f"saturation: the {axis.upper()} command was at its limit ({lo:+g} / {hi:+g} V) in "
                f"{100 * s.fraction:.2f} % of samples (warning above {100 * SATURATION_WARNING_FRACTION:g} %)"
            )
    return lines
