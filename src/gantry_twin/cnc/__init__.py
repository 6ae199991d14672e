"""A real CNC drives the twin: LinuxCNC plans and interpolates a part program, the twin is its machine.

LinuxCNC (GPL-2) runs as separate programs, talked to over files, pipes and
HAL, never loaded into the twin's process (docs/linuxcnc.md):
:mod:`~gantry_twin.cnc.config` (the machine's INI and HAL files, a user's INI read),
:mod:`~gantry_twin.cnc.session` (LinuxCNC's processes, started and stopped in one place),
:mod:`~gantry_twin.cnc.canon` (a program as ``rs274`` reads it),
:mod:`~gantry_twin.cnc.offline` (a program run headless, its commands recorded),
:mod:`~gantry_twin.cnc.reference` (the recorded commands as the loop's reference) and
:mod:`~gantry_twin.cnc.live` (the twin as LinuxCNC's machine, in real time: docs/linuxcnc.md, "The live mode").
"""
