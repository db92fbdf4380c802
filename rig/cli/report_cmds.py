"""CLI: rig report, rig export-cal, rig sessions."""

from __future__ import annotations

import click


def register(group: click.Group) -> None:
    """Add this module's commands to the `rig` group."""
