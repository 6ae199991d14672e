"""Cost of FMI in the 0.2 ms loop (docs/fmi.md, "What it costs").

    PYTHONPATH=src python benchmarks/bench_fmi.py [--only controller] [--seconds 4] [--repeats 5]

``controller``: the per-sample CPU of a native controller FMU in the compiled loop over the built-in ``pd``'s,
side by side in one run. The FMU is examples/fmu-pd/pd.c (the same law as ``pd``, built with gcc by
examples/fmu-pd/build.py), run with pd's gains on the no-load circle on ``Plant()`` (models/gantry.xml); both
loops are compiled (and warmed up) first, then timed interleaved, ``--repeats`` times each, ``--seconds``
simulated per run, best of each. CPU is the process's (``time.process_time``: every thread), wall beside it. The
bar is 1.3 (the FMU's loop at most 1.3 times pd's). Also, for the record: the same law as an FMU built with
pythonfmu (examples/fmu-pd/pypd.py), which runs on the Python loop, one run, over ``pd``'s compiled loop.
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from gantry_twin import Plant, TimingLaw, circle, simulate
from gantry_twin.controllers import PD
from gantry_twin.fmi import fmu_controller

ROOT = Path(__file__).resolve().parents[1]
#: The FMU's loop over pd's, per-sample CPU: the bar it must stay within.
BAR = 1.3
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
    w0, c0 = time.perf_counter(), time.process_time()
    trace = simulate(plant, path, timing, controller, seconds, backend=backend)
    return time.perf_counter() - w0, time.process_time() - c0, trace.filled


def controller_cost(seconds: float, repeats: int) -> None:
    """The first line: the native controller FMU's per-sample CPU over pd's, in the compiled loop."""
    with tempfile.TemporaryDirectory() as tmp:
        fmu = _build_pd_fmu(Path(tmp))
        pd = PD()
        ours = fmu_controller(fmu, parameters=_gains(pd))
        for controller in (pd, ours):  # compile or load both loops, and warm up, before timing
            _timed(controller, 0.1)
        best = {"pd": (np.inf, np.inf), "fmu": (np.inf, np.inf)}
        samples = 0
        for _ in range(repeats):
            for name, controller in (("pd", pd), ("fmu", ours)):
                wall, cpu, samples = _timed(controller, seconds)
                best[name] = (min(best[name][0], wall), min(best[name][1], cpu))
        per = {name: (w / samples * 1e6, c / samples * 1e6) for name, (w, c) in best.items()}
        ratio = per["fmu"][1] / per["pd"][1]
        verdict = "within" if ratio <= BAR else "OVER"
        print(
            f"controller FMU (native, compiled loop) over pd: {ratio:.2f}x per-sample CPU ({verdict} the {BAR}x bar); "
            f"fmu {per['fmu'][1]:.2f} us CPU ({per['fmu'][0]:.2f} us wall), pd {per['pd'][1]:.2f} us CPU "
            f"({per['pd'][0]:.2f} us wall) per sample; best of {repeats} runs of {samples} samples each, interleaved"
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


PARTS = {"controller": controller_cost}


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
