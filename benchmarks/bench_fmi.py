"""Cost of FMI (docs/fmi.md, "What it costs"): a controller FMU in the 0.2 ms loop, and the plant as an FMU.

    PYTHONPATH=src python benchmarks/bench_fmi.py [--only controller|plant] [--seconds 4] [--repeats 5]

``controller``: the per-sample CPU of a native controller FMU in the compiled loop over the built-in ``pd``'s,
side by side in one run. The FMU is examples/fmu-pd/pd.c (the same law as ``pd``, built with gcc by
examples/fmu-pd/build.py), run with pd's gains on the no-load circle on ``Plant()`` (models/gantry.xml); the
loops are compiled (and warmed up) first, then timed interleaved, ``--repeats`` times each, ``--seconds``
simulated per run, best of each. CPU is every process's and thread's: this one's and its reaped children's
(``getrusage``: the FMU's runs go in a worker process, gantry_twin.loop.worker), wall beside it. The bar is 1.3
(the FMU's loop at most 1.3 times pd's). Second line: the FMU in its worker process (every run's) over the same
FMU run in this process (``isolation`` None: the loop as it was before the worker), side by side: per sample (the
CPU each added sample costs, between the runs of ``--seconds`` and runs of 0.02 s; the bar is 1.05), the CPU a run
costs more whatever its length (the fork, copy-on-write, the worker's end: the runs of 0.02 s), and the whole
runs' ratio, with the spread of the runs and the load. Also, for the record: the same law as an FMU built with pythonfmu
(examples/fmu-pd/pypd.py), which runs on the Python loop, one run, over ``pd``'s compiled loop.

``plant``: the exported plant FMUs (``gantry-twin fmu export``, the rig plant: the native one, and the pythonfmu one
of ``--python``) against the twin's own compiled loop on the same plant (``simulate`` with ``pd``), side by side in
one run. Each master closes the built-in ``pd`` around the FMU on the no-load circle, its law computed at every
communication point and held over the step. First the native FMU from a C master (benchmarks/fmi_plant_master.c:
``fmi2GetReal``, pd in C, ``fmi2SetReal``, ``fmi2DoStep`` at 0.2 ms, its loop's CPU read by itself, every
thread): the FMU's own cost with nothing around it, held to the bar, 1.2x the twin's loop per sample. Then both
FMUs from fmpy's FMU2Slave (pd in Python): fmi2DoStep's CPU per sample as a Python master sees it, ctypes and
fmpy's wrapper included (the master's whole CPU, ``time.process_time``, less that of the same loop without the
fmi2DoStep calls), the native one at 0.2 ms and 1 ms steps, the pythonfmu one at 0.2 ms. Timed interleaved,
``--repeats`` times each, ``--seconds`` simulated per run: best of each over the twin's best, the spread of the
runs and the load average beside them.
"""

from __future__ import annotations

import argparse
import copy
import importlib.util
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave

from gantry_twin import Plant, TimingLaw, circle, simulate
from gantry_twin.controllers import PD
from gantry_twin.fmi import fmu_controller
from gantry_twin.fmi.plant import OUTPUTS
from gantry_twin.fmi.plant_export import export_plant
from gantry_twin.fmi.plant_native import c_compiler
from gantry_twin.paths.contours import ReferenceStream

ROOT = Path(__file__).resolve().parents[1]
#: The FMU's loop over pd's, per-sample CPU: the bar it must stay within.
BAR = 1.3
#: The native plant FMU's fmi2DoStep at 0.2 ms over the twin's own loop, per-sample CPU: its bar.
PLANT_BAR = 1.2
#: The FMU in its worker process over the same FMU in this process, per-sample CPU: the bar it must stay within.
WORKER_BAR = 1.05
#: The short runs that measure what a run costs apart from its samples, s simulated.
SHORT_S = 0.02
#: The no-load circle's rate (scenarios/no_load_circle.yaml).
CIRCLE_RATE_RAD_S = 2.0


def _build_pd_fmu(out: Path) -> Path:
    spec = importlib.util.spec_from_file_location("fmu_pd_build", ROOT / "examples" / "fmu-pd" / "build.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.build_fmu(out)


def _gains(pd: PD) -> dict[str, float]:
    return {
        f"{gain}_{axis}": float(value[i])
        for gain, value in (("kp", pd.kp_v_m), ("kd", pd.kd_v_s_m), ("kv", pd.kv_v_s_m), ("ka", pd.ka_v_s2_m))
        for i, axis in enumerate("xy")
    }


def _timed(controller, seconds: float, backend: str = "auto") -> tuple[float, float, int]:  # noqa: ANN001
    """(wall s, CPU s of every thread, samples) of one run of the no-load circle (compiled when the controller
    offers a compiled step: pd and a native FMU)."""
    plant, path, timing = Plant(), circle(), TimingLaw(CIRCLE_RATE_RAD_S, "on_path")
    w0, c0 = time.perf_counter(), _cpu_s()
    trace = simulate(plant, path, timing, controller, seconds, backend=backend)
    return time.perf_counter() - w0, _cpu_s() - c0, trace.filled


def _cpu_s() -> float:
    """CPU s of this process (every thread) and of its children that ended (the loop's worker processes)."""
    return sum(
        usage.ru_utime + usage.ru_stime
        for usage in (resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN))
    )


def controller_cost(seconds: float, repeats: int) -> None:
    """The first line: the native controller FMU's per-sample CPU over pd's, in the compiled loop."""
    with tempfile.TemporaryDirectory() as tmp:
        fmu = _build_pd_fmu(Path(tmp))
        pd = PD()
        ours = fmu_controller(fmu, parameters=_gains(pd))
        here = copy.copy(ours)
        here.isolation = None  # the same FMU, the loop in this process
        loops = (("pd", pd, seconds), ("fmu", ours, seconds), ("here", here, seconds))
        loops += (("fmu short", ours, SHORT_S), ("here short", here, SHORT_S))
        for _, controller, _ in loops:  # compile or load the loops, and warm up, before timing
            _timed(controller, 0.1)
        cpus: dict[str, list[float]] = {name: [] for name, _, _ in loops}
        best = {name: (np.inf, np.inf) for name, _, _ in loops}
        samples: dict[str, int] = {}
        for _ in range(repeats):
            for name, controller, length_s in loops:
                wall, cpu, samples[name] = _timed(controller, length_s)
                cpus[name].append(cpu)
                best[name] = (min(best[name][0], wall), min(best[name][1], cpu))
        per = {name: (w / samples[name] * 1e6, c / samples[name] * 1e6) for name, (w, c) in best.items()}
        ratio = per["fmu"][1] / per["pd"][1]
        verdict = "within" if ratio <= BAR else "OVER"
        print(
            f"controller FMU (native, compiled loop, in its worker process) over pd: {ratio:.2f}x per-sample CPU "
            f"({verdict} the {BAR}x bar); fmu {per['fmu'][1]:.2f} us CPU ({per['fmu'][0]:.2f} us wall), pd "
            f"{per['pd'][1]:.2f} us CPU ({per['pd'][0]:.2f} us wall) per sample; best of {repeats} runs of "
            f"{samples['pd']} samples each, interleaved"
        )
        # The worker's cost: per sample, the slope between the long and the short runs (CPU per added sample); per
        # run, what the short runs cost more (the fork, copy-on-write of the pages either process writes, the end).
        added = samples["fmu"] - samples["fmu short"]
        slope = {name: (best[name][1] - best[f"{name} short"][1]) / added * 1e6 for name in ("fmu", "here")}
        worker = slope["fmu"] / slope["here"]
        fixed_ms = (best["fmu short"][1] - best["here short"][1]) * 1e3
        whole = best["fmu"][1] / best["here"][1]
        spread = {name: (max(c) - min(c)) / min(c) * 100 for name, c in cpus.items()}
        print(
            f"controller FMU in its worker process over the same FMU in this process: {worker:.3f}x per-sample CPU "
            f"({'within' if worker <= WORKER_BAR else 'OVER'} the {WORKER_BAR}x bar; {slope['fmu']:.2f} against "
            f"{slope['here']:.2f} us per sample added, runs of {seconds:g} s less runs of {SHORT_S:g} s) and "
            f"{fixed_ms:.1f} ms of CPU more per run (runs of {SHORT_S:g} s); whole runs of {seconds:g} s "
            f"{whole:.3f}x; every process counted, best of {repeats} each, spread {spread['fmu']:.0f} % and "
            f"{spread['here']:.0f} %; load {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores"
        )
        python = _python_fmu(Path(tmp), pd)
        if python is None:
            print("controller FMU that needs Python: pythonfmu is not installed, not measured")
            return
        wall, cpu, n = _timed(python, min(seconds, 1.0))
        print(
            f"controller FMU built with pythonfmu (Python loop): {cpu / n * 1e6:.1f} us CPU per sample "
            f"({wall / n * 1e6:.1f} us wall), {cpu / n * 1e6 / per['pd'][1]:.1f}x pd's compiled loop; one run of "
            f"{n} samples"
        )


def _python_fmu(where: Path, pd: PD):  # noqa: ANN202
    """examples/fmu-pd/pypd.py built with pythonfmu, as a controller at pd's gains (None without pythonfmu)."""
    if importlib.util.find_spec("pythonfmu") is None:
        return None
    source = ROOT / "examples" / "fmu-pd" / "pypd.py"
    command = [sys.executable, "-m", "pythonfmu", "build", "-f", str(source), "-d", str(where)]
    subprocess.run(command, check=True, capture_output=True)
    return fmu_controller(where / "pypd.fmu", parameters=_gains(pd))


TS = 2e-4


def _twin_loop(seconds: float) -> tuple[float, float, int]:
    """(wall s, CPU s, samples) of the twin's compiled loop with pd on the rig plant."""
    plant, path, timing = Plant.shipped("rig"), circle(), TimingLaw(CIRCLE_RATE_RAD_S, "on_path")
    w0, c0 = time.perf_counter(), time.process_time()
    trace = simulate(plant, path, timing, PD(), seconds)
    return time.perf_counter() - w0, time.process_time() - c0, trace.filled


def _fmu_loop(fmu: Path, unpacked: str, seconds: float, step_s: float, step: bool = True) -> tuple[float, float, int]:
    """(wall s inside fmi2DoStep, the master's CPU s, samples) of pd closed around the plant FMU by fmpy; with
    ``step`` False the same loop without the fmi2DoStep calls (the master's own CPU, subtracted)."""
    md = read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    n = int(round(seconds / step_s))
    per = int(round(step_s / TS))
    ref = ReferenceStream(circle(), TimingLaw(CIRCLE_RATE_RAD_S, "on_path")).next(np.arange(n) * step_s)
    pd = PD()
    kp, kd, kv, ka = (np.asarray(g, dtype=float) for g in (pd.kp_v_m, pd.kd_v_s_m, pd.kv_v_s_m, pd.ka_v_s2_m))
    slave = FMU2Slave(guid=md.guid, unzipDirectory=unpacked, modelIdentifier="GantryPlant", instanceName="plant")
    slave.instantiate()
    in_step = 0.0
    try:
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        start = ("start.x_m", "start.y_m", "start.dx_m_s", "start.dy_m_s")
        slave.setReal([vr[s] for s in start], [*ref.q_d[0], *ref.dq_d[0]])
        slave.exitInitializationMode()
        measured, commands = [vr[s] for s in OUTPUTS[:4]], [vr["u_x_v"], vr["u_y_v"]]
        c0 = time.process_time()
        for k in range(n):
            x, y, dx, dy = slave.getReal(measured)
            e, de = np.array([x, y]) - ref.q_d[k], np.array([dx, dy]) - ref.dq_d[k]
            u = np.clip(-kp * e - kd * de + kv * ref.dq_d[k] + ka * ref.ddq_d[k], -10.0, 10.0)
            slave.setReal(commands, list(u))
            w = time.perf_counter()
            if step:
                slave.doStep(k * step_s, step_s)
            in_step += time.perf_counter() - w
        cpu = time.process_time() - c0
        slave.terminate()
    finally:
        slave.freeInstance()
    return in_step, cpu, n * per


def _spread(values: list[float]) -> str:
    return f"{min(values):.2f} to {max(values):.2f}"


def _c_master(where: Path) -> Path:
    """benchmarks/fmi_plant_master.c compiled against fmpy's FMI 2.0 headers, with the compiler the export used."""
    import fmpy

    compiler = c_compiler()
    master = where / "fmi_plant_master"
    headers = Path(fmpy.__file__).parent / "c-code"
    source = ROOT / "benchmarks" / "fmi_plant_master.c"
    subprocess.run([compiler, "-O2", f"-I{headers}", str(source), "-ldl", "-o", str(master)], check=True)
    return master


def _c_loop(master: Path, fmu: Path, unpacked: str, seconds: float, where: Path) -> tuple[float, float, int]:
    """(0, CPU s of the C master's loop, samples): pd in C closed around the native FMU at 0.2 ms steps."""
    md = read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    n = int(round(seconds / TS))
    ref = ReferenceStream(circle(), TimingLaw(CIRCLE_RATE_RAD_S, "on_path")).next(np.arange(n) * TS)
    pd = PD()
    gains = [pd.kp_v_m[0], pd.kd_v_s_m[0], *pd.kv_v_s_m, *pd.ka_v_s2_m]
    assert pd.kp_v_m[0] == pd.kp_v_m[1] and pd.kd_v_s_m[0] == pd.kd_v_s_m[1]  # one kp, one kd in the C
    rows = np.vstack([np.column_stack([ref.q_d, ref.dq_d, ref.ddq_d]), np.asarray(gains, dtype=float)])
    reference = where / "reference.bin"
    reference.write_bytes(np.ascontiguousarray(rows, dtype=np.float64).tobytes())
    names = ("start.x_m", "start.y_m", "start.dx_m_s", "start.dy_m_s", *OUTPUTS[:4], "u_x_v", "u_y_v")
    command = [str(master), unpacked, md.guid, str(reference), *(str(vr[name]) for name in names)]
    done = subprocess.run(command, capture_output=True, text=True, check=True, timeout=600)
    samples, cpu = done.stdout.split()
    return 0.0, float(cpu), int(samples)


def plant_cost(seconds: float, repeats: int) -> None:
    """The plant FMUs' fmi2DoStep over the twin's own loop, per sample: the native FMU at 0.2 ms and 1 ms steps and
    the pythonfmu FMU at 0.2 ms, side by side in one run. fmi2DoStep's CPU per sample is the master's CPU
    (time.process_time: every thread) less that of the same master loop without the fmi2DoStep calls, run
    interleaved with it; the twin's loop is ``simulate`` with pd on the rig plant. The bar: the native FMU's at
    0.2 ms at most 1.2x the twin's loop."""
    with tempfile.TemporaryDirectory() as tmp:
        fmus = {
            kind: export_plant(Path(tmp) / f"{kind}.fmu", python=kind == "python").path for kind in ("native", "python")
        }
        unpacked = {kind: extract(str(fmu), str(Path(tmp) / kind)) for kind, fmu in fmus.items()}
        master = _c_master(Path(tmp))
        runs = {
            "twin": lambda s: _twin_loop(s),
            "native, C master": lambda s: _c_loop(master, fmus["native"], unpacked["native"], s, Path(tmp)),
            "native 0.2 ms": lambda s: _fmu_loop(fmus["native"], unpacked["native"], s, TS),
            "master 0.2 ms": lambda s: _fmu_loop(fmus["native"], unpacked["native"], s, TS, step=False),
            "native 1 ms": lambda s: _fmu_loop(fmus["native"], unpacked["native"], s, 5 * TS),
            "master 1 ms": lambda s: _fmu_loop(fmus["native"], unpacked["native"], s, 5 * TS, step=False),
            "python 0.2 ms": lambda s: _fmu_loop(fmus["python"], unpacked["python"], s, TS),
        }
        for run in runs.values():  # compile or load the kernels, warm up
            run(0.1)
        cpu = {name: [] for name in runs}
        wall = {name: [] for name in runs}
        load = [os.getloadavg()[0]]
        for _ in range(repeats):
            for name, run in runs.items():
                w, c, samples = run(seconds)
                cpu[name].append(c / samples * 1e6)
                wall[name].append(w / samples * 1e6)
            load.append(os.getloadavg()[0])
        twin = min(cpu["twin"])
        print(f"twin's loop (compiled, pd, rig plant): {twin:.2f} us CPU per sample (runs {_spread(cpu['twin'])})")
        ours = min(cpu["native, C master"])
        verdict = "within" if ours / twin <= PLANT_BAR else "OVER"
        print(
            f"native plant FMU, 0.2 ms steps, pd in a C master (fmi2GetReal, fmi2SetReal, fmi2DoStep, the law): "
            f"{ours:.2f} us CPU per sample, {ours / twin:.2f}x the twin's loop ({verdict} the {PLANT_BAR}x bar; "
            f"runs {_spread(cpu['native, C master'])} us)"
        )
        for name, master in (
            ("native 0.2 ms", "master 0.2 ms"),
            ("native 1 ms", "master 1 ms"),
            ("python 0.2 ms", "master 0.2 ms"),
        ):
            step = [c - m for c, m in zip(cpu[name], cpu[master], strict=True)]
            best = min(cpu[name]) - min(cpu[master])
            ratio = best / twin
            print(
                f"plant FMU, {name}, fmpy master: fmi2DoStep {best:.2f} us CPU per sample, {ratio:.2f}x the twin's "
                f"loop "
                f"(runs {_spread(step)} us; {min(wall[name]):.2f} us wall inside fmi2DoStep)"
            )
        print(
            f"best of {repeats} runs of {seconds:g} s simulated each, interleaved; load average "
            f"{min(load):.1f} to {max(load):.1f}"
        )
        for where in unpacked.values():
            shutil.rmtree(where, ignore_errors=True)


PARTS = {"controller": controller_cost, "plant": plant_cost}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", choices=sorted(PARTS), help="run only this part")
    parser.add_argument("--seconds", type=float, default=4.0, help="simulated seconds per timed run (default 4)")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs of each loop (default 5)")
    args = parser.parse_args(argv)
    for name, part in PARTS.items():
        if args.only in (None, name):
            part(args.seconds, args.repeats)
    return 0


if __name__ == "__main__":
    sys.exit(main())
