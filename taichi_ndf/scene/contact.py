"""The `[[obstacles]]` tables and the `[contact]` table of a scene file (docs/scenes.md)."""

from __future__ import annotations

from pathlib import Path

from taichi_ndf.contact import (
    Capsule,
    ContactConfig,
    Cylinder,
    GroundPlane,
    MeshObstacle,
    RoundedBox,
    Sphere,
)
from taichi_ndf.contact.config import DEFAULT_CHECK_RESOLUTION
from taichi_ndf.scene.schema import SceneError, Table, checked

OBSTACLES = ("plane", "sphere", "box", "capsule", "cylinder", "mesh")
ZERO = (0.0, 0.0, 0.0)


def parse_contact(top: Table, model, base_dir: Path) -> ContactConfig | None:
    """The model's contact settings from `[[obstacles]]` and `[contact]`, or None when the
    scene has no obstacles (a `[contact]` table without obstacles is an error)."""
    tables = top.tables("obstacles")
    settings = top.table("contact", optional=True)
    if not tables:
        if settings.data:
            raise SceneError("contact: the scene has no [[obstacles]]")
        settings.close()
        return None
    obstacles, friction = [], []
    for k, t in enumerate(tables):
        obstacles.append(checked(lambda t=t, k=k: _obstacle(t, k, base_dir), t.path))
        friction.append(t.number("friction", 0.0, nonnegative=True))
        t.close()
    activation = _auto(settings, "activation_distance")
    stiffness = _auto(settings, "stiffness")
    margin = None if settings._get("margin", "auto") == "auto" else \
        settings.number("margin", nonnegative=True)
    resolution = settings.integer("check_resolution", DEFAULT_CHECK_RESOLUTION, minimum=2)
    settings.close()
    return checked(lambda: ContactConfig.resolve(
        obstacles, model, margin=margin, activation=activation, stiffness=stiffness,
        check_resolution=resolution, friction=tuple(friction)), "obstacles")


def _auto(t: Table, name: str) -> float | None:
    """A positive number, or None for "auto" (the default)."""
    if t._get(name, "auto") == "auto":
        return None
    return t.number(name, positive=True)


def _obstacle(t: Table, index: int, base_dir: Path):
    kind = t.string("type", choices=OBSTACLES)
    name = t.string("name", f"{kind}_{index}")
    motion = t.vector("motion", 3, ZERO)
    if kind == "plane":
        return GroundPlane(name=name, point=t.vector("point", 3, ZERO),
                           normal=t.vector("normal", 3, (0.0, 0.0, 1.0)),
                           size=t.number("size", 2.0, positive=True), motion=motion)
    if kind == "sphere":
        return Sphere(name=name, centre=t.vector("centre", 3),
                      radius=t.number("radius", positive=True), motion=motion)
    if kind == "box":
        return RoundedBox(name=name, centre=t.vector("centre", 3),
                          half_extents=t.vector("half_extents", 3),
                          rounding=t.number("rounding", 0.0, nonnegative=True), motion=motion)
    if kind in ("capsule", "cylinder"):
        cls = Capsule if kind == "capsule" else Cylinder
        return cls(name=name, start=t.vector("start", 3), end=t.vector("end", 3),
                   radius=t.number("radius", positive=True), motion=motion)
    path = Path(t.string("path"))
    if not path.is_absolute():
        path = base_dir / path
    if not path.is_file():
        raise SceneError(f"{t.key('path')}: obstacle mesh not found: {path}")
    return MeshObstacle.from_file(path, name=name, scale=t.number("scale", 1.0, positive=True),
                                  offset=t.vector("offset", 3, ZERO), motion=motion)
