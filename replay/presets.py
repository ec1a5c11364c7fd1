"""Part and bin geometry: the numbers both the config (paper §5.4 parameters, a_max) and the
synthetic scenes need, in millimetres.

The config imports this module, never the scene generator: replaying a real log loads no synthesis
code.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class PartKind:
    """Geometry of one part kind, in millimetres (the numbers the paper's §5.4 presets need).

    Attributes
    ----------
    name : str
        Key in :data:`PART_KINDS`.
    label : str
        What the paper calls it (Figure 8).
    p_min_mm : float
        Smallest edge of the part's bounding box (paper §5.4, sets the z-cut step and max depth).
    face_area_mm2 : float
        Area of the largest face the sensor sees (``a_max`` in mm²; divide by the pixel footprint
        squared for pixels, see :func:`face_area_px`).
    shiny : bool
        Polished or zinc-plated metal (many outliers) versus black oxide (few).
    bounding_radius_mm : float
        Radius of a sphere about the part origin that contains the solid.
    """

    name: str
    label: str
    p_min_mm: float
    face_area_mm2: float
    shiny: bool
    bounding_radius_mm: float


# Dimensions: ISO 4032 M12 nut (s = 18, m = 10.8, bore 10.5 shown), ISO 4017 M12 x 40 bolt
# (head s = 18, k = 7.5), M16 rod 80 mm long, 20 mm balls, ANSI-40 20-tooth plate sprocket
# (88 mm outside, 7 mm thick, 16 mm bore).
HEX_S_MM, HEX_M_MM, NUT_BORE_MM = 18.0, 10.8, 10.5
HEX_AREA_MM2 = math.sqrt(3.0) / 2.0 * HEX_S_MM**2
SPROCKET_R_ROOT_MM, SPROCKET_R_TIP_MM, SPROCKET_TEETH, SPROCKET_T_MM, SPROCKET_BORE_MM = 38.0, 44.0, 20, 7.0, 8.0

PART_KINDS: dict[str, PartKind] = {
    "spheres": PartKind("spheres", "metal spheres", 20.0, math.pi * 10.0**2, True, 10.0),
    "zinc_nuts": PartKind(
        "zinc_nuts", "M12 zinc nuts", HEX_M_MM, HEX_AREA_MM2 - math.pi * (NUT_BORE_MM / 2) ** 2, True, 12.0
    ),
    "rods": PartKind("rods", "M16 metal rods", 16.0, 16.0 * 80.0, True, 41.0),
    "black_screws": PartKind(
        "black_screws", "M12 black screws", HEX_S_MM, 12.0 * 40.0 + 7.5 * HEX_S_MM * 2 / math.sqrt(3.0), False, 25.5
    ),
    "black_nuts": PartKind(
        "black_nuts", "M12 black nuts", HEX_M_MM, HEX_AREA_MM2 - math.pi * (NUT_BORE_MM / 2) ** 2, False, 12.0
    ),
    "sprockets": PartKind(
        "sprockets",
        "sprockets",
        SPROCKET_T_MM,
        math.pi * (SPROCKET_R_ROOT_MM**2 - SPROCKET_BORE_MM**2) + SPROCKET_TEETH * 0.5 * (6.0 + 2.5) * 6.0,
        True,
        44.5,
    ),
}


@dataclass(frozen=True, slots=True)
class BinGeometry:
    """The plastic bin, in millimetres.

    Attributes
    ----------
    outer_length_mm, outer_width_mm : float
        Outer size of the rim (x, y in the bin frame).
    height_mm : float
        Rim top above the table (``b_h`` of paper §5.4).
    rim_mm : float
        Width of the flat rim (wall top plus flange) seen from above.
    floor_mm : float
        Floor thickness: the inner floor is this high above the table.
    draft_deg : float
        Draft of the inner walls (the opening narrows towards the floor).
    """

    outer_length_mm: float = 400.0
    outer_width_mm: float = 300.0
    height_mm: float = 120.0
    rim_mm: float = 15.0
    floor_mm: float = 3.0
    draft_deg: float = 4.0

    @property
    def inner_top_half(self) -> tuple[float, float]:
        return self.outer_length_mm / 2 - self.rim_mm, self.outer_width_mm / 2 - self.rim_mm

    @property
    def floor_half(self) -> tuple[float, float]:
        """Half sizes of the flat inner floor."""
        inset = (self.height_mm - self.floor_mm) * math.tan(math.radians(self.draft_deg))
        lx, ly = self.inner_top_half
        return lx - inset, ly - inset

    def as_metadata(self) -> dict[str, str]:
        return {
            "bin_outer_length_mm": f"{self.outer_length_mm:g}",
            "bin_outer_width_mm": f"{self.outer_width_mm:g}",
            "bin_height_mm": f"{self.height_mm:g}",
            "bin_rim_mm": f"{self.rim_mm:g}",
            "bin_floor_mm": f"{self.floor_mm:g}",
            "bin_draft_deg": f"{self.draft_deg:g}",
        }


BIN = BinGeometry()
