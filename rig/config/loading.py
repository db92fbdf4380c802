"""A plan and its station, loaded for a run, a check or a design: the station's commissioning file (when
its field source names one) checked and applied, so that nothing downstream uses a field source the rig
has not been told how much to trust.

    campaign = load_campaign("configs/plans/demo.yaml", station_path=None)
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from rig.config import Campaign, commissioning_file, read_campaign


def load_campaign(plan_path: str | Path, station_path: str | Path | None = None) -> Campaign:
    campaign = read_campaign(plan_path, station_path)
    commissioned = commissioning_file.load_for_station(campaign.station, campaign.station_path,
                                                        campaign.station_text)
    return replace(campaign, station=commissioning_file.apply(campaign.station, commissioned))
