"""Test scenes for Mitsuba 3, built in code: Mitsuba's Cornell box and three harder variants.

Each function returns a scene dictionary for ``mi.load_dict`` (a variant must be set), with a
box reconstruction filter so that images from different integrators compare pixel by pixel.

* ``cornell``: Mitsuba's Cornell box (``mi.cornell_box()``), lit from the ceiling.
* ``hidden``: the same box with a panel just below the light: the light reaches the room only
  off the ceiling around the panel, so next-event estimation finds it almost nowhere.
* ``door``: the box's left wall opens, through a gap a door open a crack leaves, into a second
  room that holds the only light: all the light enters through the gap.
* ``glossy``: the Cornell box with a rough metal floor and rough plastic boxes.
"""

from __future__ import annotations

import mitsuba as mi


def T():
    """An identity transform to chain on (a variant must be set)."""
    return mi.ScalarTransform4f()


NAMES = ("cornell", "hidden", "door", "glossy")


def _box_filter(scene: dict, size: int, max_depth: int) -> dict:
    film = scene["sensor"]["film"]
    film["width"] = film["height"] = size
    film["rfilter"] = {"type": "box"}
    scene["integrator"] = {"type": "path", "max_depth": max_depth}
    return scene


def _rectangle(to_world, bsdf: str | dict = "white", **extra) -> dict:
    bsdf_ref = {"type": "ref", "id": bsdf} if isinstance(bsdf, str) else bsdf
    return {"type": "rectangle", "to_world": to_world, "bsdf": bsdf_ref, **extra}


def cornell(size: int = 128, max_depth: int = 8) -> dict:
    return _box_filter(mi.cornell_box(), size, max_depth)


def hidden(size: int = 128, max_depth: int = 8) -> dict:
    scene = cornell(size, max_depth)
    # The light is 0.46 × 0.38 at y = 0.99, facing down; the panel, 0.6 × 0.5, hangs below it.
    scene["panel"] = _rectangle(
        T().translate([0.0, 0.9, 0.0]).rotate([1, 0, 0], 90).scale([0.3, 0.25, 1.0]),
        {"type": "twosided", "bsdf": {"type": "ref", "id": "white"}},
    )
    return scene


def door(size: int = 128, max_depth: int = 10) -> dict:
    scene = cornell(size, max_depth)
    del scene["light"], scene["red-wall"]
    white = {"type": "twosided", "bsdf": {"type": "ref", "id": "white"}}
    red = {"type": "twosided", "bsdf": {"type": "ref", "id": "red"}}

    # The left wall (x = -1, z in [-1, 1], y in [-1, 1]) with a gap at z in [-0.25, -0.1],
    # y in [-1, 0.6]: four pieces around it.
    def wall_piece(z0, z1, y0, y1):
        return _rectangle(
            T()
            .translate([-1.0, (y0 + y1) / 2, (z0 + z1) / 2])
            .rotate([0, 1, 0], 90)
            .scale([(z1 - z0) / 2, (y1 - y0) / 2, 1.0]),
            red,
        )

    scene["wall-back"] = wall_piece(-1.0, -0.25, -1.0, 1.0)
    scene["wall-front"] = wall_piece(-0.1, 1.0, -1.0, 1.0)
    scene["wall-lintel"] = wall_piece(-0.25, -0.1, 0.6, 1.0)

    # The second room: x in [-3, -1], the same height and depth, closed on every side.
    def room(name, transform):
        scene[name] = _rectangle(transform, white)

    room(
        "next-floor", T().translate([-2.0, -1.0, 0.0]).rotate([1, 0, 0], -90).scale([1.0, 1.0, 1.0])
    )
    room(
        "next-ceiling", T().translate([-2.0, 1.0, 0.0]).rotate([1, 0, 0], 90).scale([1.0, 1.0, 1.0])
    )
    room("next-back", T().translate([-2.0, 0.0, -1.0]).scale([1.0, 1.0, 1.0]))
    room("next-front", T().translate([-2.0, 0.0, 1.0]).scale([1.0, 1.0, 1.0]))
    room("next-far", T().translate([-3.0, 0.0, 0.0]).rotate([0, 1, 0], 90).scale([1.0, 1.0, 1.0]))
    # Its light, on its ceiling, facing down: the Cornell box's, 16 times as bright, so that
    # the little that comes through the gap lights the first room about as brightly.
    scene["light"] = {
        "type": "rectangle",
        "to_world": T().translate([-2.2, 0.99, 0.3]).rotate([1, 0, 0], 90).scale([0.23, 0.19, 1.0]),
        "bsdf": {"type": "ref", "id": "white"},
        "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [294.2, 223.8, 108.1]}},
    }
    return scene


def glossy(size: int = 128, max_depth: int = 8) -> dict:
    scene = cornell(size, max_depth)
    scene["metal"] = {"type": "roughconductor", "material": "Al", "alpha": 0.08}
    scene["plastic"] = {
        "type": "roughplastic",
        "alpha": 0.1,
        "diffuse_reflectance": {"type": "rgb", "value": [0.6, 0.55, 0.5]},
    }
    scene["floor"]["bsdf"] = {"type": "ref", "id": "metal"}
    scene["small-box"]["bsdf"] = {"type": "ref", "id": "plastic"}
    scene["large-box"]["bsdf"] = {"type": "ref", "id": "plastic"}
    return scene


def build(name: str, size: int = 128) -> dict:
    """The scene dictionary called ``name`` (one of ``NAMES``)."""
    makers = {"cornell": cornell, "hidden": hidden, "door": door, "glossy": glossy}
    if name not in makers:
        raise ValueError(f"unknown scene {name!r}: one of {', '.join(NAMES)}")
    return makers[name](size)
