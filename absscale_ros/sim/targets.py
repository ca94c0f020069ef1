"""Calibration objects of the paper: letter / A4 sheet and the 0.8 m tri-colour cube."""
import colorsys

import numpy as np

from absscale_ros.sim.scene import (box_corners, CUBE_AXIS_COLOURS, CUBE_FACES,
                                    face_vertex_ids, FloatArray, Material, rot_z, Target)

SHEETS_M = {'letter': (0.2159, 0.2794), 'a4': (0.210, 0.297)}
CUBE_EDGE_M = 0.8
# Fig. 2's exact values are not in the text: saturated red, yellow, purple (HSV, H in degrees).
CUBE_HSV = {'red': (0.0, 0.90, 0.85), 'yellow': (55.0, 0.90, 0.90), 'purple': (290.0, 0.75, 0.70)}
# Own-frame axis that points up in the world for each top colour (columns: images of x, y, z).
_TOP = {'purple': np.eye(3),
        'red': np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]),
        'yellow': np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])}
PAPER = Material('paper', (1.0, 1.0, 1.0), 0.0005)


def colour_rgb(name: str) -> tuple[float, float, float]:
    """Display RGB in [0, 1] of a named paint colour (``CUBE_HSV``)."""
    h, s, v = CUBE_HSV[name]
    r, g, b = colorsys.hsv_to_rgb(h / 360.0, s, v)
    return (r, g, b)


def paint(name: str) -> Material:
    """Painted plywood of a ``CUBE_HSV`` colour."""
    return Material('paint', colour_rgb(name), 0.001)


def sheet(kind: str, centre_m: FloatArray, yaw_rad: float) -> Target:
    """
    A sheet lying flat (normal +z) at ``centre_m``; corners counter-clockwise from above.

    :param kind: ``letter`` or ``a4``.
    """
    w, h = SHEETS_M[kind]
    verts = rectangle(centre_m, yaw_rad, w, h)
    edges = ((0, 1), (1, 2), (2, 3), (3, 0))
    return Target('sheet', kind, (w, h), verts, edges, ((0, 1, 2, 3),), ('white',))


def rectangle(centre_m: FloatArray, yaw_rad: float, width_m: float,
              height_m: float) -> FloatArray:
    """(4, 3) corners of a horizontal rectangle, counter-clockwise seen from above."""
    w, h = width_m, height_m
    local = np.array([[-w, -h, 0.0], [w, -h, 0.0], [w, h, 0.0], [-w, h, 0.0]]) * 0.5
    return np.asarray(centre_m, float) + local @ rot_z(yaw_rad).T


def cube(centre_xy_m: FloatArray, ground_z_m: float, yaw_rad: float, top: str) -> Target:
    """
    The 0.8 m cube standing on the ground; opposite faces share a colour.

    :param top: colour of the top (and bottom) face.
    """
    R = rot_z(yaw_rad) @ _TOP[top]
    centre = np.array([centre_xy_m[0], centre_xy_m[1], ground_z_m + 0.5 * CUBE_EDGE_M])
    verts = box_corners(centre, np.full(3, CUBE_EDGE_M), 0.0, rotation=R)
    edges = tuple((i, i | (1 << k)) for i in range(8) for k in range(3) if not i & (1 << k))
    faces = tuple(face_vertex_ids(axis, sign) for axis, sign in CUBE_FACES)
    colours = tuple(CUBE_AXIS_COLOURS[axis] for axis, _ in CUBE_FACES)
    return Target('cube', f'cube_{CUBE_EDGE_M:g}', (CUBE_EDGE_M,) * 3, verts, edges, faces,
                  colours)
