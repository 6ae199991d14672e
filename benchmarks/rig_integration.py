"""The rig plant's integration: the chosen Euler x8 against 2 us RK4 physics, 1 s of every shipped scenario.

    PYTHONPATH=src python benchmarks/rig_integration.py

The shipped scenarios on ``plant.model=rig`` (models/rig.xml) with its LuGre friction spelled out (a scenario's
``plant.friction`` replaces the file's whole, so the reference's integrator comes with the same parameters),
under the same 0.2 ms control; prints the largest |eps_c - eps_c_ref| with the encoder's quantisation off (the
integration error alone) and as shipped (docs/rig-plant.md, docs/friction.md "Integration").
"""

import numpy as np

from gantry_twin.plant.model import Plant
from gantry_twin.run import execute
from gantry_twin.scenario import build, load_scenario, shipped_scenarios

rig = Plant.shipped("rig").friction
friction = ["plant.model=rig", "plant.friction.model=lugre"]
for axis in ("x", "y"):
    a = getattr(rig, axis)
    friction += [
        f"plant.friction.{axis}.{k}={getattr(a, k)!r}"
        for k in ("sigma0_n_m", "sigma1_ns_m", "fc_n", "fs_n", "vs_m_s", "sigma2_ns_m")
    ]
base = ["duration_s=1.0", "window_s=[0.0, 1.0]", "estimates_window_s=[0.0, 1.0]", "monitor.enable=false"]
reference = ["plant.friction.integrator=rk4", "plant.friction.substeps=100"]
for path in shipped_scenarios():
    out = []
    for quant in (["sensing.quantize=false"], []):
        eps = []
        for extra in ([], reference):
            built = build(load_scenario(path, [*base, *friction, *extra, *quant]))
            assert built.plant.offset.y.constant_v > 0 and built.plant.friction.lugre
            trace = execute(built)
            assert not any(w.number for w in built.plant.data.warning)
            eps.append(np.asarray(trace.eps_c_m))
        out.append(np.abs(eps[0] - eps[1]).max() * 1e6)
    print(f"{path.stem:28s} no quantisation {out[0]:.3f} um   encoder as shipped {out[1]:.3f} um", flush=True)
