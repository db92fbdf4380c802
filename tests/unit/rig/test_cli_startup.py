"""A new `rig` process imports only what its command needs, and gives the same calibration whichever
path (compiled or plain) its input takes."""

import os
import subprocess
import sys
from pathlib import Path

import click
import numpy as np
import pytest

from calib import compiled, synthetic
from calib.io import calfile, csvfast, csvio
from calib.models import gram_kernel
from rig import cli

HEAVY = ("numpy", "pyarrow", "numba", "pydantic", "rich", "yaml", "matplotlib", "rig.config")


def _in_new_process(code: str, **env) -> str:
    """stdout of `code` run by a fresh interpreter (the environment plus `env`)."""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                          env={**os.environ, **env})
    return done.stdout


def _imported_after(argv: list[str], **env) -> set[str]:
    out = _in_new_process(
        "import contextlib, io, sys\n"
        "from rig.cli import main\n"
        "with contextlib.redirect_stdout(io.StringIO()) as text:\n"
        f"    code = main({argv!r})\n"
        "assert code == 0, (code, text.getvalue())\n"
        f"print(' '.join(m for m in {HEAVY!r} if m in sys.modules))\n",
        **env,
    )
    return set(out.split())


def test_every_command_is_registered_by_the_module_the_lazy_group_names():
    for module in set(cli.COMMAND_MODULES.values()):
        group = click.Group()
        __import__(f"rig.cli.{module}", fromlist=["register"]).register(group)
        named = {name for name, home in cli.COMMAND_MODULES.items() if home == module}
        assert set(group.commands) == named, module


def test_rig_version_imports_nothing_heavy():
    assert _imported_after(["--version"]) == set()
    assert "magrig, version" in _in_new_process("from rig.cli import main; main(['--version'])")


@pytest.fixture
def t24_csv(tmp_path):
    ds, _ = synthetic.t24_dataset(np.random.default_rng(5), samples_per_point=6)
    ds.group = None
    path = tmp_path / "t24.csv"
    csvio.write_csv(path, csvio.contract_columns(ds))
    return path


def test_a_csv_refit_leaves_numba_and_the_campaign_code_alone(t24_csv, tmp_path):
    out = tmp_path / "cal.yaml"
    imported = _imported_after(["refit", str(t24_csv), "--model", "t24", "-o", str(out)])
    assert "numba" not in imported and "rig.config" not in imported  # a small file: the plain paths
    assert {"numpy", "pyarrow"} <= imported
    assert calfile.load(out).model == "t24"


def _params(path: Path) -> dict:
    return calfile.load(path).params


def test_refit_gives_the_same_calibration_with_and_without_numba(t24_csv, tmp_path, monkeypatch):
    argv = ["refit", str(t24_csv), "--model", "t24", "-o"]
    _imported_after([*argv, str(tmp_path / "new.yaml")])
    _imported_after([*argv, str(tmp_path / "plain.yaml")], MAGRIG_NO_NUMBA="1")
    new, plain = _params(tmp_path / "new.yaml"), _params(tmp_path / "plain.yaml")
    for name in plain:
        np.testing.assert_array_equal(new[name], plain[name])  # the same (plain) path
    pytest.importorskip("numba")
    monkeypatch.setattr(csvfast, "COMPILED_BREAK_EVEN_BYTES", 0)  # the compiled scanner and kernel
    monkeypatch.setattr(gram_kernel, "COMPILED_BREAK_EVEN_ROWS", 0)  # for this small file too
    assert compiled.worth_compiled(1, 0)
    assert cli.main([*argv, str(tmp_path / "compiled.yaml")]) == 0
    compiled_params = _params(tmp_path / "compiled.yaml")
    for name in plain:
        np.testing.assert_allclose(compiled_params[name], plain[name], rtol=1e-9, atol=1e-9)


def test_numba_is_worth_loading_only_for_big_inputs_whatever_the_process_loaded(monkeypatch):
    pytest.importorskip("numba")  # loaded in this process: it changes nothing
    assert not compiled.worth_compiled(10**6, 10**7) and compiled.worth_compiled(10**7, 10**7)
    monkeypatch.setenv("MAGRIG_NO_NUMBA", "1")
    assert not compiled.worth_compiled(10**9, 10**7)
