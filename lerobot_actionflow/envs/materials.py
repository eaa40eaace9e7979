"""Materials for the tasks written here (robosuite's bundled textures only)."""

from __future__ import annotations

from robosuite.models.objects import CompositeObject
from robosuite.utils.mjcf_utils import CustomMaterial


def textured(texture: str, name: str) -> CustomMaterial:
    """A cube-mapped material from one of robosuite's textures (``"WoodRed"``, ``"Metal"``, ...)."""
    return CustomMaterial(
        texture=texture,
        tex_name=name,
        mat_name=f"{name}_mat",
        tex_attrib={"type": "cube"},
        mat_attrib={"texrepeat": "1 1", "specular": "0.4", "shininess": "0.1"},
    )


def box_composite(
    name: str, *, materials: list[CustomMaterial], geom_materials: list[int], **kwargs
) -> CompositeObject:
    """A robosuite ``CompositeObject`` whose geoms use our materials: ``geom_materials[i]`` is
    the index in ``materials`` of geom ``i``'s material (robosuite wants names at construction
    and the material assets appended afterwards)."""
    obj = CompositeObject(
        name=name,
        geom_materials=[materials[i].name for i in geom_materials],
        geom_rgbas=[None] * len(geom_materials),
        **kwargs,
    )
    for mat in materials:
        obj.append_material(mat)
    return obj
