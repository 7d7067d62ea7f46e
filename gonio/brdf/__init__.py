"""Reflectance models: one module per paper family, one registry, one dispatcher.

>>> from gonio import brdf
>>> "ward" in brdf.names()
True

Registered names and their equations are listed in ``docs/architecture.md``; ``brdf.spec(name)``
gives each model's parameters with bounds, units and defaults.
"""

from gonio.brdf import (  # noqa: F401  (importing registers the models)
    lafortune,
    lambert,
    li_torrance,
    measured,
    neumann,
    oren_nayar,
    tabulated,
    ward,
    ward_gmd,
)
from gonio.brdf.base import (
    BRDF,
    CallableBRDF,
    ModelSpec,
    Param,
    as_brdf,
    create,
    get_class,
    names,
    register,
    spec,
)
from gonio.brdf.composite import Sum

__all__ = [
    "BRDF",
    "CallableBRDF",
    "ModelSpec",
    "Param",
    "Sum",
    "as_brdf",
    "create",
    "get_class",
    "names",
    "register",
    "spec",
]
