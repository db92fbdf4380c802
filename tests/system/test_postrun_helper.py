"""The post-run fits of many DUTs on two cores (rig/analysis/fithelper.py): a campaign on the shipped 16-DUT
station has its fits shared with a helper process, whose calibration files are byte for byte the ones
the run's own process writes; a helper that dies leaves its DUTs to the run's process."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile

import pytest

from rig.analysis import dutfits, fithelper
from rig.config import load_station
from tests.system.campaign_helpers import REPO, quick_demo, run_rig

pytestmark = pytest.mark.system

STATION = REPO / "configs" / "stations" / "sim-16.yaml"
MODELS = ("t24", "p12")


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    folder = tmp_path_factory.mktemp("helper")
    proc = run_rig("run", str(quick_demo(folder, samples=1)), "--station", str(STATION), "--out", str(folder),
                   "--no-live", timeout=300)
    assert proc.returncode in (0, 3), proc.stderr[-2000:]
    return next(folder.glob("*.session"))


def _files(session) -> dict[str, list[bytes]]:
    """The calibration files beside the session, each but the line of when it was made."""
    return {p.name: [line for line in p.read_bytes().splitlines() if not line.startswith(b"created_utc:")]
            for p in sorted(session.parent.glob("*.yaml")) if p.name.count(".") >= 3}


def test_a_helper_fits_part_of_the_duts_and_writes_what_the_run_writes_itself(session):
    duts = [d.name for d in load_station(STATION).duts]
    told: list[str] = []
    helped = {dut: {f.pid for f in fits} for dut, fits in fithelper.fitted_duts(session, MODELS, False, duts,
                                                                               told.append)}
    assert sorted(told) == sorted(duts) and set(helped) == set(duts)
    here = {dut for dut, pids in helped.items() if pids == {os.getpid()}}
    assert 0 < len(here) < len(duts)  # both processes fitted DUTs
    shared = _files(session)
    assert len(shared) >= 2 * len(duts)
    with dutfits.SessionFits(session, MODELS, False) as alone:
        for dut in duts:
            alone.fit(dut)
    assert _files(session) == shared


def test_a_helper_that_dies_leaves_its_duts_to_the_run(session, monkeypatch, caplog):
    def dying(*_):
        proc = subprocess.Popen([sys.executable, "-c", "import sys; sys.exit('out of memory')"],
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=errors)
        return fithelper.Helper(proc, errors)

    errors = tempfile.TemporaryFile()
    monkeypatch.setattr(fithelper.Helper, "start", dying)
    duts = [d.name for d in load_station(STATION).duts]
    fitted = dict(fithelper.fitted_duts(session, MODELS, False, duts, lambda dut: None))
    assert set(fitted) == set(duts)
    assert all(f.pid == os.getpid() and f.error is None for fits in fitted.values() for f in fits)
    said = [r.getMessage() for r in caplog.records if "helper process" in r.getMessage()]
    assert len(said) == 1 and "code 1 (out of memory)" in said[0]


class _PromptHelper:
    """A helper that has answered each DUT by the time the run looks (a fast helper beside a slow run):
    the run must never wait for an answer when it has handed out nothing."""

    alive = True

    def __init__(self):
        self.answers: list[str] = []

    def give(self, dut):
        self.answers.append(dut)

    def results(self, block):
        if block and not self.answers:
            raise AssertionError("waited for the helper with nothing handed to it")
        while self.answers:
            dut = self.answers.pop(0)
            yield dut, [dutfits.DutFit(dut, "t24")]


class _Here:
    def fit(self, dut):
        return [dutfits.DutFit(dut, "t24")]


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 16])
def test_the_run_never_waits_for_a_helper_that_holds_nothing(n):
    duts = [f"dut{k}" for k in range(n)]
    out = list(fithelper._shared_out(_Here(), _PromptHelper(), list(duts), lambda dut: None))
    assert sorted(dut for dut, _ in out) == sorted(duts)


def test_a_helper_started_with_the_run_takes_its_share_and_ctrl_c_never_reaches_it(session):
    """Started as the run starts, it waits through the run; Ctrl-C at the terminal goes to the terminal's
    foreground process group, the run's, and the helper is in a group of its own."""
    duts = [d.name for d in load_station(STATION).duts]
    with fithelper.run_helper(session, MODELS, False, len(duts)) as helper:
        assert helper is not None and os.getpgid(helper.proc.pid) != os.getpgid(0)
        helped = {dut: {f.pid for f in fits} for dut, fits in fithelper.fitted_duts(
            session, MODELS, False, duts, lambda dut: None, helper)}
    assert set(helped) == set(duts)
    assert {helper.proc.pid} in helped.values() and {os.getpid()} in helped.values()
    assert helper.proc.returncode == 0
