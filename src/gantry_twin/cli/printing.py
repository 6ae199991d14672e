"""What the command line prints of a run: the short summary, the health lines, the whole-run figures."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from gantry_twin.health.monitor import Alarm
from gantry_twin.outputs.plots import run_label


def format_summary(data: dict[str, Any], wall_time_s: float, out: Path | None = None, files: Sequence[str] = ()) -> str:
    """The short human summary ``run`` prints (``files``: those written into ``out``)."""
    c = data["contour_error_um"]
    lines = [
        f"{run_label(data)}: {data['duration_s']:g} s simulated ({data['steps']} steps) in {wall_time_s:.1f} s",
        f"contour error eps_c over [{c['window_s'][0]:.3f}, {c['window_s'][1]:.3f}] s (window_s): "
        f"rms {c['rms']:.3f} um, max {c['max']:.3f} um",
        *whole_run_lines(data),
    ]
    if "estimates" in data:
        w = data["estimates_window_s"]
        lines.append(f"estimates (mean over [{w[0]:.3f}, {w[1]:.3f}] s)  estimate     true    error")
        for name, e in data["estimates"].items():
            pct = "      -" if e["error_pct"] is None else f"{e['error_pct']:+7.2f} %"
            lines.append(f"  {name:<4} {e['estimate']:12.5f} {e['true']:8.4f}  {pct}")
    if "health" in data:
        lines.extend(format_health(data["health"]))
    if out is not None:
        lines.append(f"results in {out}/" + (f" ({', '.join(files)})" if files else ""))
    return "\n".join(lines)


def format_health(health: dict[str, Any]) -> list[str]:
    """The health monitor's alarms and per-parameter status, for the printed summary."""
    alarms = health["alarms"]
    lines = [
        f"health: {len(alarms)} alarm{'' if len(alarms) == 1 else 's'}"
        + (f" (baseline: {health['baseline']['source']})" if "baseline" in health else "")
    ]
    for a in alarms:  # summary.json's alarms hold exactly an Alarm's fields
        cleared = "" if a["cleared_s"] is None else f", cleared at {a['cleared_s']:.2f} s"
        lines.append(f"  ALARM {Alarm(**a).describe()}{cleared}")
    status = health["status"]
    if status:
        lines.append("  status at the end: " + ", ".join(f"{n} {s}" for n, s in status.items()))
    ex = ", ".join(
        f"{axis} {e['level_v_final']:.3g} V"
        for axis, e in health["excitation"].items()
        if e["level_v_final"] is not None
    )
    if ex:
        lines.append(f"  excitation level at the end (sqrt lambda_min, eq. 29): {ex}")
    return lines


#: The printed summary lists the rms of each period when the run has at most this many (else the first and last).
PERIODS_PRINTED = 12


def whole_run_lines(data: dict[str, Any]) -> list[str]:
    """The printed lines of summary.json's whole-run figures, each with its window (none for an older summary)."""
    whole, periods = data.get("whole_run"), data.get("contour_error_per_period_um")
    lines = []
    if whole is not None:
        (a, b), (ca, cb) = whole["window_s"], whole["command_window_s"]
        c, e, u = whole["contour_error_um"], whole["axial_error_rms_um"], whole["max_abs_command_v"]
        lines += [
            f"contour error eps_c over [{a:.3f}, {b:.3f}] s (whole run from the start of window_s): "
            f"rms {c['rms']:.3f} um, max {c['max']:.3f} um",
            f"axial error e over [{a:.3f}, {b:.3f}] s: rms " + ", ".join(f"{k} {v:.3f} um" for k, v in e.items()),
            f"command u over [{ca:.3f}, {cb:.3f}] s: max |u| " + ", ".join(f"{k} {v:.3f} V" for k, v in u.items()),
        ]
        saturation = data.get("saturation")
        if saturation:
            lines[-1] += "; at the limit " + ", ".join(
                f"{k} {100 * s['fraction']:.2f} %" for k, s in saturation.items()
            )
    if periods is not None and periods["rms"]:
        rms = periods["rms"]
        shown = " ".join(f"{v:.3f}" for v in rms)
        if len(rms) > PERIODS_PRINTED:
            half = PERIODS_PRINTED // 2
            shown = " ".join(f"{v:.3f}" for v in rms[:half]) + " ... " + " ".join(f"{v:.3f}" for v in rms[-half:])
        lines.append(
            f"rms eps_c per period of {periods['period_s']:.3f} s from {periods['start_s']:.3f} s "
            f"({len(rms)} period{'' if len(rms) == 1 else 's'}, the last up to the end): {shown} um"
        )
    return lines
