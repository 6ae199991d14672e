"""The fitted plant as an MJCF file a scenario can use (``plant: {file: DIR/plant.xml}``): the machine's bodies
included whole (a copy of models/gantry.xml beside it) and the fitted properties as the ``<custom>`` numerics
that :func:`gantry_twin.plant.effects.file_properties` reads (docs/rig-plant.md), as models/rig.xml carries them."""

from __future__ import annotations

from xml.sax.saxutils import escape

from gantry_twin.plant.effects import NUMERIC
from gantry_twin.plant.model import Plant
from gantry_twin.theta import AXES

#: The machine's file the plant file includes (copied beside it).
BODIES_FILE = "gantry.xml"


def _numbers(values: list[float]) -> str:
    return " ".join(f"{v:.12g}" for v in values)


def plant_xml(plant: Plant, command: str, values: dict[str, float]) -> str:
    """The MJCF text of ``plant``'s friction (if LuGre), input offset and force ripple, with a comment on the
    command and the fitted values that made it."""
    fitted = "\n".join(f"    {name} = {value:.6g}" for name, value in values.items())
    lines = [
        "<!--",
        "  gantry-twin: a calibrated plant, written by (- - stands for the two hyphens a comment cannot hold)",
        f"    {escape(command).replace('--', '- -')}",
        "  the fitted values:",
        escape(fitted),
        "  The machine's bodies are gantry.xml's (included); the numerics are read by",
        "  gantry_twin.plant.effects.file_properties (docs/rig-plant.md). Use: plant: {file: <this file>}.",
        "-->",
        '<mujoco model="gantry_calibrated">',
        f'  <include file="{BODIES_FILE}"/>',
        "  <custom>",
    ]
    for axis, lugre in zip(AXES, plant.lugre_parameters(), strict=True):
        if lugre is not None:
            numbers = [lugre.sigma0_n_m, lugre.sigma1_ns_m, lugre.fc_n, lugre.fs_n, lugre.vs_m_s]
            lines.append(f'    <numeric name="{NUMERIC["lugre"].format(axis=axis)}" data="{_numbers(numbers)}"/>')
            lines.append(
                f'    <numeric name="{NUMERIC["viscous"].format(axis=axis)}" data="{_numbers([lugre.sigma2_ns_m])}"/>'
            )
        offset = getattr(plant.offset, axis)
        lines.append(
            f'    <numeric name="{NUMERIC["input_offset"].format(axis=axis)}" '
            f'data="{_numbers([offset.constant_v, offset.half_travel_v])}"/>'
        )
        ripple = getattr(plant.ripple, axis)
        numbers = [ripple.pitch_m, *(v for h in ripple.harmonics for v in (h.amplitude_v, h.phase_rad))]
        lines.append(f'    <numeric name="{NUMERIC["force_ripple"].format(axis=axis)}" data="{_numbers(numbers)}"/>')
    lines += ["  </custom>", "</mujoco>", ""]
    return "\n".join(lines)
