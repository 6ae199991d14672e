"""``gantry-twin sweep``: plan -> cluster -> points as they finish -> results.parquet, figures, summary.md."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from gantry_twin.outputs.signals import stop_signals_interrupt
from gantry_twin.sweep.engine import run_batch
from gantry_twin.sweep.plots import SUMMARY_FILE, write_figures, write_summary
from gantry_twin.sweep.points import STATUS_OK, Plan, failed_row, run_point
from gantry_twin.sweep.table import RESULTS_FILE, ResultsTable, earlier_sweep

#: Where ``keep_runs`` puts each point's run files (``<out>/runs/<key>/``, the files of ``gantry-twin run``).
RUNS_DIR = "runs"


@dataclass(frozen=True)
class SweepOutcome:
    """What a sweep did: points in the plan, done before (``--resume``), run now, failed now, and its times, s.

    startup_s: from the start to the workers warmed up (cluster, imports,
    compiling or loading the loop); points_s: from the first point submitted
    to the last result written; wall_time_s: the whole call.
    """

    total: int
    done_before: int
    ran: int
    failed: int
    wall_time_s: float
    startup_s: float
    points_s: float
    results: Path


def existing_results(out: Path) -> Path | None:
    """The results file of an earlier sweep in ``out``, if any."""
    path = Path(out) / RESULTS_FILE
    return path if path.exists() else None


def set_aside(out: Path) -> str:
    """``--fresh``: move an earlier sweep's files in ``out`` (results.parquet, summary.md, the figures, runs/) into
    ``out/replaced-<UTC time>/``; returns the one line that says what was moved where (nothing is deleted)."""
    out = Path(out)
    earlier = earlier_sweep(out / RESULTS_FILE)
    names = [RESULTS_FILE, SUMMARY_FILE, RUNS_DIR]
    moving = [p for p in sorted(out.iterdir()) if p.name in names or p.suffix == ".png"]
    if not moving:
        return ""
    aside = out / time.strftime("replaced-%Y%m%dT%H%M%SZ", time.gmtime())
    aside.mkdir()
    for path in moving:
        path.rename(aside / path.name)
    figures = sum(p.suffix == ".png" for p in moving)
    what = f"sweep {Path(str(earlier.get('source', '?'))).name}, plan {earlier.get('plan_key', '?')}"
    moved = ", ".join(p.name for p in moving if p.suffix != ".png") + (f" and {figures} figures" if figures else "")
    return f"--fresh: the earlier sweep's files in {out} ({what}): {moved} moved to {aside}"


def run_sweep(
    plan: Plan,
    out: Path,
    workers: int | None = None,
    scheduler: str | None = None,
    resume: bool = False,
    progress: bool = False,
) -> SweepOutcome:
    """Run the points of ``plan`` not yet done (all of them without ``resume``) and write the outputs.

    ``results.parquet`` is rewritten as each point finishes; the figures and
    summary.md at the end, or on an interrupt (KeyboardInterrupt, also
    raised by SIGTERM here) for the points finished so far, after the
    cluster has been shut down.
    """
    out = Path(out)
    started = time.perf_counter()
    _remove_stale_temporaries(out)
    table = ResultsTable(plan, out / RESULTS_FILE)
    done_before = table.load() if resume else 0
    todo = [p for p in plan.points if not table.done(p)]
    failed = 0
    keep = plan.spec.keep_runs
    changed = not todo  # nothing to run: the figures and summary are made again
    ready = finished = started
    try:
        with stop_signals_interrupt():
            if todo:
                marks: list[float] = []
                arguments = [(p.resolved, plan.scenario_source, keep) for p in todo]
                batch = run_batch(
                    run_point,
                    arguments,
                    [p.resolved for p in todo],
                    plan.scenario_source,
                    workers,
                    scheduler,
                    progress,
                    "sweep",
                    len(plan.points),
                    done_before,
                    on_ready=lambda: marks.append(time.perf_counter()),
                )
                for index, result, error in batch:
                    point = todo[index]
                    row = failed_row(error) if error is not None else result.row
                    failed += row["status"] != STATUS_OK
                    if result is not None and result.files:
                        _write_run_files(out / RUNS_DIR / point.key, result.files)
                    table.add(point, row)
                    changed = True
                ready = marks[0] if marks else started
                finished = time.perf_counter()
            if not todo or not table.path.exists():  # e.g. --resume dropped rows of points no longer swept
                table.write()
    finally:
        rows = list(table.rows.values())
        if rows and changed:
            write_summary(plan, rows, write_figures(plan, rows, out), out)
    wall = time.perf_counter() - started
    return SweepOutcome(
        len(plan.points), done_before, len(todo), failed, wall, ready - started, finished - ready, table.path
    )


def _remove_stale_temporaries(out: Path) -> None:
    """The temporaries an earlier sweep in ``out`` left when it was killed (results.parquet's, the figures', a kept
    run's files): those whose process is gone; a sweep still running in ``out`` keeps its own."""
    from gantry_twin.outputs.files import remove_stale_temporaries

    remove_stale_temporaries(out)
    runs = out / RUNS_DIR
    if runs.is_dir():
        for directory in runs.iterdir():
            if directory.is_dir() and not directory.is_symlink():
                remove_stale_temporaries(directory)


def _write_run_files(directory: Path, files: dict[str, bytes]) -> None:
    from gantry_twin.outputs.files import atomic_write
    from gantry_twin.run import SUMMARY_FILE

    # summary.json last: present means the run's other files are complete (as gantry-twin run writes them).
    for name in sorted(files, key=lambda n: n == SUMMARY_FILE):
        atomic_write(directory / name, lambda fh, data=files[name]: fh.write(data))
