"""``python -m gantry_twin.cli``: the ``gantry-twin`` command."""

from gantry_twin.cli.app import main

raise SystemExit(main())
