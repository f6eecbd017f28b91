"""Building blocks of the scenario schema: strict models, shapes, angles.

Every section of a scenario file (core or contributed by a paper package) is a
:class:`StrictModel`: unknown keys are errors, values are immutable once
loaded. Shapes are tagged unions on ``type``. Angles are written in degrees in
files and converted to radians by the code that consumes them.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

import shapely
from pydantic import BaseModel, ConfigDict, Field, GetCoreSchemaHandler, model_validator
from pydantic_core import CoreSchema, PydanticCustomError, core_schema
from shapely.geometry.base import BaseGeometry

COORD_LIMIT = 1e6
"""Largest magnitude of a coordinate or length in a scenario file (workcell units).

Workcells are described in any unit (millimetres to metres); a million units leaves room
for all of them while keeping every geometric computation far from float overflow."""
Coord = Annotated[float, Field(ge=-COORD_LIMIT, le=COORD_LIMIT, allow_inf_nan=False)]
Length = Annotated[float, Field(gt=0, le=COORD_LIMIT, allow_inf_nan=False)]
Vec2 = tuple[Coord, Coord]
PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegativeFloat = Annotated[float, Field(ge=0, allow_inf_nan=False)]
Probability = Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)]
CELLS_RANGE: tuple[int, int] = (4, 4096)
"""Allowed grid cells per configuration-space axis, everywhere (files, CLI, library)."""
Cells = Annotated[int, Field(ge=CELLS_RANGE[0], le=CELLS_RANGE[1])]

NAME_PATTERN = r"^[A-Za-z0-9_.\-]+$"
"""What a name (of an obstacle, part, region, goal ...) may hold."""
Name = Annotated[str, Field(min_length=1, pattern=NAME_PATTERN)]


BOOL_NOT_NUMBER = "expected a number, not true or false"
"""The one refusal of a boolean where a scenario expects a number (see :class:`StrictModel`)."""


def _refuse_bool(value: Any) -> Any:
    if isinstance(value, bool):
        raise PydanticCustomError("bool_not_number", BOOL_NOT_NUMBER)
    return value


def _numeric_literal(schema: dict[str, Any]) -> bool:
    expected = schema.get("expected", [])
    return any(isinstance(v, int | float) and not isinstance(v, bool) for v in expected)


def strict_numbers(schema: Any) -> Any:
    """``schema`` (a pydantic core schema) with booleans refused wherever it expects a number.

    pydantic reads ``true`` as 1 for an ``int``, a ``float`` or ``Literal[1]``, so YAML's
    ``cellplan: true`` passed as format version 1 and ``true`` as a coordinate. Every
    ``int``, ``float`` and numeric-literal node is wrapped in a check that refuses a
    boolean; integers and floats are otherwise read as before.
    """
    if isinstance(schema, list):
        return [strict_numbers(item) for item in schema]
    if not isinstance(schema, dict):
        return schema
    out = {key: strict_numbers(value) for key, value in schema.items()}
    kind = out.get("type")
    if kind in ("int", "float") or (kind == "literal" and _numeric_literal(out)):
        return core_schema.no_info_before_validator_function(_refuse_bool, out)
    return out


class StrictModel(BaseModel):
    """Base of every scenario model: unknown keys are errors, values are frozen, and a
    boolean is never a number (:func:`strict_numbers`)."""

    # A string literal under a field is its description in the JSON Schema.
    model_config = ConfigDict(
        extra="forbid", frozen=True, allow_inf_nan=False, use_attribute_docstrings=True
    )

    @classmethod
    def __get_pydantic_core_schema__(
        cls, source: type[BaseModel], handler: GetCoreSchemaHandler
    ) -> CoreSchema:
        # The one place numeric types become strict: every section's model, core or
        # contributed by a package, derives from this class.
        schema: CoreSchema = strict_numbers(handler(source))
        return schema


class PolygonShape(StrictModel):
    """A simple polygon (convex or not) given by its vertices in order."""

    type: Literal["polygon"] = Field(default="polygon", description="shape kind")
    points: list[Vec2] = Field(
        min_length=3,
        max_length=10_000,
        description="vertices (workcell units), in either winding order",
        examples=[[[0, 0], [4, 0], [2, 3]]],
    )

    @model_validator(mode="after")
    def _simple_and_non_degenerate(self) -> PolygonShape:
        if (
            abs(shapely.Polygon(self.points).area) <= 1e-12
            and shapely.Polygon(self.points).convex_hull.area <= 1e-12
        ):
            raise ValueError("polygon is degenerate (zero area)")
        if not shapely.LinearRing(self.points).is_simple:
            raise ValueError("polygon is self-intersecting")
        return self

    def to_shapely(self) -> BaseGeometry:
        return shapely.Polygon(self.points)


class BoxShape(StrictModel):
    """An axis-aligned rectangle ``[min, max]``; shorthand for a four-point polygon."""

    type: Literal["box"] = Field(description="shape kind")
    min: Vec2 = Field(description="lower-left corner (workcell units)", examples=[[2, 2]])
    max: Vec2 = Field(description="upper-right corner (workcell units)", examples=[[6, 5]])

    @model_validator(mode="after")
    def _ordered(self) -> BoxShape:
        if not (self.max[0] > self.min[0] and self.max[1] > self.min[1]):
            raise ValueError("box needs max > min on both axes")
        return self

    def to_shapely(self) -> BaseGeometry:
        return shapely.box(self.min[0], self.min[1], self.max[0], self.max[1])


class DiscShape(StrictModel):
    """A closed disc."""

    type: Literal["disc"] = Field(description="shape kind")
    center: Vec2 = Field(description="centre (workcell units)", examples=[[5, 5]])
    radius: Length = Field(description="radius (workcell units)", examples=[1.0])

    def to_shapely(self) -> BaseGeometry:
        # Only for drawing and reference checks; collision code uses the exact disc.
        return shapely.Point(self.center).buffer(self.radius, quad_segs=32)


Shape = Annotated[PolygonShape | BoxShape | DiscShape, Field(discriminator="type")]
RigidShape = Annotated[PolygonShape | BoxShape, Field(discriminator="type")]


class Bounds(StrictModel):
    """The rectangular workcell ``[xmin, xmax] x [ymin, ymax]``."""

    xmin: Coord = Field(default=0.0, description="left edge (workcell units)", examples=[0])
    ymin: Coord = Field(default=0.0, description="bottom edge (workcell units)", examples=[0])
    xmax: Coord = Field(description="right edge (workcell units)", examples=[100])
    ymax: Coord = Field(description="top edge (workcell units)", examples=[100])

    @model_validator(mode="after")
    def _ordered(self) -> Bounds:
        if not (self.xmax > self.xmin and self.ymax > self.ymin):
            raise ValueError("bounds need xmax > xmin and ymax > ymin")
        return self

    def to_shapely(self) -> BaseGeometry:
        return shapely.box(self.xmin, self.ymin, self.xmax, self.ymax)


__all__ = [
    "BOOL_NOT_NUMBER",
    "CELLS_RANGE",
    "COORD_LIMIT",
    "NAME_PATTERN",
    "Bounds",
    "BoxShape",
    "Cells",
    "Coord",
    "DiscShape",
    "Length",
    "Name",
    "NonNegativeFloat",
    "PolygonShape",
    "PositiveFloat",
    "Probability",
    "RigidShape",
    "Shape",
    "StrictModel",
    "Vec2",
    "strict_numbers",
]
