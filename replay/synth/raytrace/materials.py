"""Surface materials of the ray-traced scene: a diffuse albedo, a specular share and a roughness.

The reflectance model is a Lambertian term plus a Beckmann-like specular lobe,
``f = albedo / pi + specular * D(h) / (4 cos_i cos_o)`` with
``D(h) = exp(-tan^2 θ_h / roughness^2) / (pi roughness^2 cos^4 θ_h)``: enough to place the
projector's highlights where a mirror puts them and to let a shiny surface reflect what the
projector lights elsewhere. Surfaces with ``specular >= MIRROR_MIN`` also pass light on by
reflection (the interreflections of :mod:`replay.synth.raytrace.optics`).

The numbers are engineering assumptions, not measurements (``docs/raytraced.md`` lists them):
polished steel balls nearly mirrors, ground rods and machined sprockets a little rougher, zinc
plating duller, black oxide dark and nearly matte (paper §6: shiny parts of Figure 8a–c,f, matte
d and e), the bin bright plastic, the table dark.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from replay.synth.parts import PART_COLOURS
from replay.synth.scene import BIN_COLOUR, TABLE_COLOUR


@dataclass(frozen=True, slots=True)
class Material:
    """Reflectance of one surface.

    Attributes
    ----------
    albedo : float
        Diffuse reflectance (0..1).
    specular : float
        Share of light reflected specularly (0..1).
    roughness : float
        Width of the specular lobe (radians-like slope, > 0).
    colour : (int, int, int)
        Colour of the surface in the 2-D image (0..255).
    """

    name: str
    albedo: float
    specular: float
    roughness: float
    colour: tuple[int, int, int]


#: surfaces this specular pass light on by reflection
MIRROR_MIN = 0.1

TABLE = Material("table", 0.15, 0.02, 0.4, TABLE_COLOUR)
BIN_PLASTIC = Material("bin", 0.75, 0.03, 0.3, BIN_COLOUR)
PART_MATERIALS: dict[str, Material] = {
    "spheres": Material("polished steel", 0.05, 0.60, 0.03, PART_COLOURS["spheres"]),
    "zinc_nuts": Material("zinc plating", 0.25, 0.35, 0.12, PART_COLOURS["zinc_nuts"]),
    "rods": Material("ground steel", 0.15, 0.50, 0.06, PART_COLOURS["rods"]),
    "black_screws": Material("black oxide", 0.05, 0.04, 0.35, PART_COLOURS["black_screws"]),
    "black_nuts": Material("black oxide", 0.05, 0.04, 0.35, PART_COLOURS["black_nuts"]),
    "sprockets": Material("machined steel", 0.20, 0.40, 0.10, PART_COLOURS["sprockets"]),
}


def material_table(materials: list[Material]) -> dict[str, np.ndarray]:
    """Column arrays (albedo, specular, roughness, colour) indexed by material id."""
    return {
        "albedo": np.array([m.albedo for m in materials]),
        "specular": np.array([m.specular for m in materials]),
        "roughness": np.array([m.roughness for m in materials]),
        "colour": np.array([m.colour for m in materials], np.float64),
    }
