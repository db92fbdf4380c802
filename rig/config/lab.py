"""What a calibration certificate states of who made it, for whom, and against what (ISO/IEC 17025:2017
7.8.2.1, ILAC P10), in the files that know it:

    station `lab:`        the laboratory: name, address, country, e-mail, accreditation id, place of work,
                          procedure id, the persons who authorize its certificates (`Lab`)
    station `duts[].serial`  each item's unique identity (rig/config/station.py)
    plan `customer:`, `received:`, `condition:`   for whom, when the items came in, in what state
    a reference magnetometer's calibration file, `source.certificate:`   the calibration certificate
                          that file transcribes: its id, issuer, date and expanded uncertainty
                          (`ReferenceCertificate`)

Every key is optional in the files (a station or plan without them still loads); a certificate made
without them names on every page what it does not state (rig/report/certificate_record.py).
"""

from __future__ import annotations

import datetime as dt
from pathlib import Path
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, StringConstraints, ValidationError

from rig.core.configbase import Strict
from rig.core.numbers import bounded
from rig.core.yamlload import error_from_validation, parse, read_text

Text = Annotated[str, StringConstraints(strip_whitespace=True, min_length=1, max_length=2000)]
CountryCode = Annotated[str, StringConstraints(pattern=r"^[A-Z]{2}$")]
# where the work was done, in the Digital Calibration Certificate's words (performanceLocation)
PLACES = ("laboratory", "customer", "laboratoryBranch", "customerBranch", "other")


class Person(Strict):
    name: Text
    role: Text | None = Field(None, description="their function, e.g. head of laboratory")


class Lab(Strict):
    """The calibration laboratory as its certificates name it (7.8.2.1 b, c, f, o)."""

    name: Text | None = None
    address: Text | None = Field(None, description="postal address, one line")
    country: CountryCode | None = Field(None, description="ISO 3166-1 alpha-2 code, e.g. DE")
    email: Text | None = None
    accreditation_id: Text | None = Field(
        None, description="the accreditation body's number for this laboratory (e.g. D-K-12345-01-00)")
    place_of_work: Text | None = Field(
        None, description="where the calibrations are made (its permanent facilities, a room, a customer's "
        "site)")
    performed_at: Literal[PLACES] = Field(
        "laboratory", description="laboratory, customer, laboratoryBranch, customerBranch or other")
    procedure_id: Text | None = Field(
        None, description="the documented calibration procedure these calibrations follow, with its revision")
    responsible: list[Person] = Field(
        [], description="who authorizes the certificates (name, role); the first signs")


# The keys a certificate must state of the laboratory, in the words it names them when they are missing.
LAB_ITEMS = {"name": "lab.name", "address": "lab.address", "country": "lab.country",
             "accreditation_id": "lab.accreditation_id", "place_of_work": "lab.place_of_work",
             "procedure_id": "lab.procedure_id", "responsible": "lab.responsible"}


class Customer(Strict):
    """Who asked for the calibration (7.8.2.1 e); information the customer supplied."""

    name: Text
    address: Text | None = None
    email: Text | None = None
    order: Text | None = Field(None, description="the customer's order or reference")


class ReferenceCertificate(Strict):
    """The calibration certificate a reference magnetometer's calibration file transcribes (its
    `source.certificate:`): what makes the station's field traceable to the SI (ILAC P10)."""

    id: Text = Field(description="the certificate's number")
    issuer: Text = Field(description="the laboratory that issued it")
    date: dt.date = Field(description="its date of issue")
    expanded_uncertainty_nt: bounded(gt=0, hi=1e9) = Field(
        description="U of the field the reference measures, as the certificate states it (nT)")
    coverage_factor: bounded(lo=1.0, hi=100.0) = Field(description="k of that U")
    coverage_probability: bounded(gt=0, hi=1.0) | None = None
    scope: Text | None = Field(None, description="the range the U holds over (fields, temperatures)")
    issuer_accreditation: Text | None = Field(
        None, description="the issuer's accreditation (body and number, under the ILAC MRA), or that it is "
        "a national metrology institute")
    route_to_si: Text | None = Field(
        None, description="how the issuer's own standard reaches the SI (its national metrology institute's "
        "realisation of the tesla)")


class _CertifiedSource(BaseModel):
    """A calibration file's `source:` as far as its certificate goes (its other keys are calib's)."""

    model_config = ConfigDict(extra="allow")
    certificate: ReferenceCertificate | None = None


class _CalibrationSource(BaseModel):
    model_config = ConfigDict(extra="allow")
    source: _CertifiedSource = _CertifiedSource()


def reference_certificate(path: str | Path, text: str | None = None) -> ReferenceCertificate | None:
    """The certificate a reference magnetometer's calibration file transcribes (`source.certificate:`),
    None when it states none; a ConfigError naming the file, the key and its line when it is incomplete."""
    source = str(path)
    data, lines = parse(read_text(path) if text is None else text, source)
    try:
        return _CalibrationSource.model_validate(data if isinstance(data, dict) else {}).source.certificate
    except ValidationError as exc:
        raise error_from_validation(exc, data, lines, source, _CalibrationSource) from None


def recorded_certificate(source: dict) -> tuple[ReferenceCertificate | None, str | None]:
    """(the certificate, None), or (None, what is wrong with it) of a reference calibration's `source` as
    a session recorded it; (None, None) when it states none."""
    stated = (source or {}).get("certificate")
    if stated is None:
        return None, None
    try:
        return ReferenceCertificate.model_validate(stated), None
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"])
        return None, f"source.certificate.{where}: {first['msg']}"
