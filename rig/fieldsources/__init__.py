"""Field sources: the station's `field_source:`, one module per kind, behind rig/fieldsources/base.py.

Adding one: a module here with a FieldSourceConfig
subclass (its `kind`, the field sets it makes, its reference), its driver in drivers/ with a registry
spec of role "field_source" and the same type, and one line in KINDS below.
"""

from __future__ import annotations

from typing import Annotated, Union

from pydantic import Field

from rig.fieldsources.base import FieldSourceConfig, makers_of
from rig.fieldsources.coils import Coils
from rig.fieldsources.turntable import SiteFromModel, SiteFromReference, SiteFromVector, Turntable

KINDS: tuple[type[FieldSourceConfig], ...] = (Coils, Turntable)

FieldSource = Annotated[Union[KINDS], Field(discriminator="kind")]  # noqa: UP007 - built from KINDS


__all__ = ["KINDS", "Coils", "FieldSource", "FieldSourceConfig", "SiteFromModel", "SiteFromReference",
           "SiteFromVector", "Turntable", "makers_of"]
