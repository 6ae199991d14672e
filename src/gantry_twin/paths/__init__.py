"""Where the machine is asked to go: the desired contours and their timing laws behind the ``Contour`` protocol
(:mod:`.contours`) and the task frame of eq. 1 and 4 (:mod:`.taskframe`). A new kind of path goes here (a part
program, which plans ahead, lives in :mod:`gantry_twin.gcode`)."""
