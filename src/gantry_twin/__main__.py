"""``python -m gantry_twin``: the ``gantry-twin`` command."""

from gantry_twin.cli.app import main

raise SystemExit(main())
