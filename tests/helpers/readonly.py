"""Run a command that must not be able to write into a chmod'ed read-only folder.

Tests run as root, and chmod does not stop root: the command then runs as root without the capabilities
that override file permissions (setpriv drops them from its bounding set), so the owner's r-x applies.
"""

from __future__ import annotations

import os
import shutil
import subprocess

import pytest

DROP = ["setpriv", "--bounding-set", "-dac_override,-dac_read_search,-fowner"]


def without_override(argv: list[str]) -> list[str]:
    """`argv` as a process that honours file permissions; skips the test where that cannot be had."""
    if os.geteuid() != 0:
        return argv
    if shutil.which("setpriv") is None:
        pytest.skip("running as root without setpriv: cannot drop the permission override")
    probe = subprocess.run([*DROP, "true"], capture_output=True)
    if probe.returncode != 0:
        pytest.skip(f"setpriv cannot drop capabilities here: {probe.stderr.decode().strip()}")
    return [*DROP, *argv]
