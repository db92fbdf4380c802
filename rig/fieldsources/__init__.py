"""Field sources: the station's `field_source:`, one module per kind, behind rig/fieldsources/base.py.

Adding one: a module here with a FieldSourceConfig
subclass (its `kind`, the field sets it makes, its reference), its driver in drivers/ with a registry
spec of role "field_source" and the same type, and one line in KINDS below.
"""

from __future__ import annotations

from typing import Annotated, Union, get_args

from pydantic import Field

from rig.fieldsources.base import FieldSourceConfig, makers_of
from rig.fieldsources.coils.config import Coils
from rig.fieldsources.turntable.config import SiteFromModel, SiteFromReference, SiteFromVector, Turntable

KINDS: tuple[type[FieldSourceConfig], ...] = (Coils, Turntable)

FieldSource = Annotated[Union[KINDS], Field(discriminator="kind")]  # noqa: UP007 - built from KINDS


def kind_class(kind: str) -> type[FieldSourceConfig]:
    """The registry entry of a field-source kind named in a file (e.g. a commissioning file's `kind:`)."""
    for cls in KINDS:
        if kind in get_args(cls.model_fields["kind"].annotation):
            return cls
    raise KeyError(kind)


__all__ = ["KINDS", "Coils", "FieldSource", "FieldSourceConfig", "SiteFromModel", "SiteFromReference",
           "SiteFromVector", "Turntable", "kind_class", "makers_of"]
