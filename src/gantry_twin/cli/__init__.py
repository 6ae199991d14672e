"""The command line, ``gantry-twin``: parse, load, run, print. Nothing in the package imports it."""

from gantry_twin.cli.app import main

__all__ = ["main"]
