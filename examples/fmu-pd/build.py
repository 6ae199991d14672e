"""Build pd.fmu from pd.c and modelDescription.xml with gcc (docs/fmi.md, "A controller FMU from C").

    python examples/fmu-pd/build.py [OUT_DIR]

The FMI 2.0 headers come from fmpy's package (``fmpy/c-code``: 2-clause BSD, the Modelica Association).
``-ffp-contract=off``: no fused multiply-add, so the law rounds as numba's pd does (docs/fmi.md).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import zipfile
from collections.abc import Sequence
from pathlib import Path

HERE = Path(__file__).resolve().parent
FLAGS = ("-O2", "-ffp-contract=off", "-shared", "-fPIC", "-std=c99", "-Wall", "-Wno-unused-parameter")


def fmi_headers() -> Path:
    """fmpy's copy of the FMI 2.0 headers."""
    import fmpy

    return Path(fmpy.__file__).parent / "c-code"


def build_fmu(
    out: Path,
    description: str | None = None,
    defines: Sequence[str] = (),
    name: str = "pd",
    source: Path = HERE / "pd.c",
    platform: str | None = None,
) -> Path:
    """Compile ``source`` into ``binaries/<platform>/<name>.so`` and zip it with the model description (the text
    of ``modelDescription.xml`` unless ``description`` is given) into ``out/<name>.fmu``; ``defines``: -D flags."""
    from fmpy import platform as this_platform

    gcc = shutil.which("gcc")
    if gcc is None:
        raise RuntimeError("gcc not found")
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        library = Path(tmp) / f"{name}.so"
        command = [gcc, *FLAGS, f"-I{fmi_headers()}", *(f"-D{d}" for d in defines), str(source), "-o", str(library)]
        subprocess.run(command, check=True, capture_output=True, text=True)
        fmu = out / f"{name}.fmu"
        with zipfile.ZipFile(fmu, "w", zipfile.ZIP_DEFLATED) as archive:
            text = description if description is not None else (HERE / "modelDescription.xml").read_text()
            archive.writestr("modelDescription.xml", text)
            archive.write(library, f"binaries/{platform or this_platform}/{name}.so")
    return fmu


if __name__ == "__main__":
    target = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(os.getcwd())
    print(build_fmu(target))
