"""Write the generated table of every scenario field into docs/scenarios.md ("Every field").

Usage: python tools/scenario_reference.py [--check]

The table (:func:`gantry_twin.scenario.reference.field_table`: each field's path, default and allowed range, from
the schema and the settings types) replaces what stands between its two marker lines in docs/scenarios.md.
``--check`` writes nothing and exits 1 if the committed doc differs (tests/test_scenario_reference.py checks the
same).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from gantry_twin.scenario.reference import BEGIN, END, field_table

DOC = Path(__file__).resolve().parents[1] / "docs" / "scenarios.md"


def with_table(text: str) -> str:
    """``text`` with the generated table between its markers."""
    start, stop = text.index(BEGIN), text.index(END) + len(END) + 1
    return text[:start] + field_table() + text[stop:]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if docs/scenarios.md is not up to date")
    args = parser.parse_args()
    text = DOC.read_text(encoding="utf-8")
    new = with_table(text)
    if args.check:
        return 0 if new == text else 1
    DOC.write_text(new, encoding="utf-8")
    print(f"wrote {DOC}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
