"""CLI: rig check, rig run, rig export."""

from __future__ import annotations

import click


def register(group: click.Group) -> None:
    """Add this module's commands to the `rig` group."""
