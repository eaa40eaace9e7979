"""The geometry of robosuite's ToolHang that its expert (:mod:`.tool_hang`) works with.

robosuite 1.5.2's ToolHang, read from the simulated model (metres); our env modules do not
define these:

- **stand** token: the base plate's centre (top 0.005 above it). The mount tube is centred at
  ``(0, 0.045)`` in the stand frame, 1 cm wide inside and 0.15 m tall.
- **frame** token: the corner where the rod meets the hook bar (``frame_intersection_site``),
  frame axes: local ``+z`` along the rod from its tip to the corner, the bar along local ``-x``
  to its free end at ``(-0.0912, 0, 0)`` (``frame_hang_site``), with a 1.2 cm stub standing up
  at that end; the grip (2.54 cm square, 6.35 cm long) is centred on the rod at
  ``(0, 0, -0.0338)``, the tip site at ``(0, 0, -0.2207)``. It starts lying on the table with
  local ``y`` vertical.
- **tool** token: the tool's centre, the grip (3 cm square, 8 cm long along local ``x``); the
  large hole (inner flats 0.0098 from its centre, axis local ``z``) is centred at
  ``(-0.0935, 0, 0)``. It starts lying flat (local ``z`` up).

"""

from __future__ import annotations

import math

import numpy as np

#: The tube's axis in the stand frame; heights of the base plate's top and the tube's top over
#: the stand's origin.
TUBE_IN_STAND = np.array([0.0, 0.045, 0.0])
BASE_TOP = 0.005
TUBE_TOP = 0.155
FRAME_GRIP = np.array([0.0, 0.0, -0.0338])
FRAME_TIP = np.array([0.0, 0.0, -0.2207])
BAR_END = np.array([-0.0912, 0.0, 0.0])
TOOL_HOLE = np.array([-0.0935, 0.0, 0.0])
#: The middle of the inner face of the hole's far lip (the box ``tool_hole1_hc_0``, on the side
#: away from the handle): the point that hooks over the bar.
TOOL_LIP = TOOL_HOLE + np.array([-0.0098, 0.0, 0.0])
LIP_HALF_THICKNESS = 0.0035
BAR_HALF = 0.00375


def ring_rotation(u: np.ndarray, tilt: float) -> np.ndarray:
    """Tool orientation with the hole's far lip forward along the bar (unit ``u``, horizontal,
    from its free end towards the rod): the handle (tool ``+x``) points down and out past the
    bar's end, ``tilt`` from the vertical, and the ring axis (tool ``z``) is ``-n`` with
    ``n = cos(tilt) u - sin(tilt) e_z``, the EEF approach axis of the top-down grasp."""
    ez = np.array([0.0, 0.0, 1.0])
    x = -(math.sin(tilt) * u + math.cos(tilt) * ez)
    z = -(math.cos(tilt) * u - math.sin(tilt) * ez)
    return np.column_stack([x, np.cross(z, x), z])


def lip_rest_height(tilt: float) -> float:
    """Height of :data:`TOOL_LIP` over the bar's axis when the lip, tilted ``tilt``, sits on
    the bar: half the bar (3.75 mm) plus the lip's half thickness (3.5 mm) seen at ``tilt``."""
    return BAR_HALF + LIP_HALF_THICKNESS * math.sin(tilt)
