"""Calibration: fit the twin's plant to a machine's measured contour errors (``gantry-twin calibrate``,
docs/cli.md).

* :mod:`.spec`: the calibration file (targets, free properties and ranges, the fixed base, the
  identification constraint, the optimiser's budget), validated like a scenario file.
* :mod:`.fit`: the plan (every scenario checked before anything runs), the evaluations on the sweep's batch
  runner, Nelder-Mead in the unit box, and what fit.json and evaluations.jsonl hold.
* :mod:`.plantfile`: the fitted plant as an MJCF file a scenario can use.
"""

from gantry_twin.calibration.fit import Evaluation, Fit, Plan, calibrate, lugre_fields, plan, point_overrides
from gantry_twin.calibration.spec import CalibrationSpec, calibration_file, calibrations_dir, load_calibration

__all__ = [
    "CalibrationSpec",
    "Evaluation",
    "Fit",
    "Plan",
    "calibrate",
    "calibration_file",
    "calibrations_dir",
    "load_calibration",
    "lugre_fields",
    "plan",
    "point_overrides",
]
