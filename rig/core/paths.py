"""Where a run writes: every file and folder a run creates is decided here, inside its output folder.

    session_file("sessions", "demo")                 # sessions/demo-20260101-120000.session
    calibration_file(session_path, "mmc0", "t24")    # beside the session: <stem>.mmc0.t24.yaml
    inside(out_dir, "mmc0_steps.png")                # a report figure

`inside` is the one check: the path must resolve (symlinks followed) to somewhere below the output
folder; a name holding `/`, `..` or an absolute path, or a symlink pointing elsewhere, is refused
with one line. Names go through rig/core/names.py `file_stem` first, so names from old sessions or
calibration files cannot smuggle a separator either.
"""

from __future__ import annotations

import time
from pathlib import Path

from rig.core.errors import ConfigError
from rig.core.names import file_stem


def inside(out_dir: str | Path, filename: str) -> Path:
    """out_dir / filename, refused when it would land anywhere but directly or below out_dir."""
    base = Path(out_dir)
    target = base / filename
    if Path(filename).is_absolute() or ".." in Path(filename).parts:
        raise ConfigError(f"{filename!r}: would be written outside the output folder {base}")
    resolved_base = base.resolve()
    resolved = target.resolve()
    if resolved == resolved_base or not resolved.is_relative_to(resolved_base):
        raise ConfigError(f"{target}: resolves to {resolved}, outside the output folder {base}")
    return target


def session_file(out_dir: str | Path, plan_name: str, stamp: str | None = None) -> Path:
    """A new session file for a plan in out_dir, named after the plan and the UTC time."""
    stamp = stamp or time.strftime("%Y%m%d-%H%M%S", time.gmtime())
    return inside(out_dir, f"{file_stem(plan_name)}-{stamp}.session")


def calibration_file(session_path: str | Path, dut: str, model: str) -> Path:
    """The calibration file of one DUT and model, beside its session."""
    session_path = Path(session_path)
    stem = session_path.name.removesuffix(".session")
    return inside(session_path.parent, f"{stem}.{file_stem(dut)}.{file_stem(model)}.yaml")
