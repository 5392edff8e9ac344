"""Workpieces of flat plates and their straight seams: V-groove butt, fillet T, lap and corner joints."""

from __future__ import annotations

import math

import numpy as np
from weldcell.hal.sim.mesh_tools import (
    check_nonnegative,
    check_positive,
    check_spacing,
    extrude_yz,
    line_seam,
    merge_parts,
    require,
    triangle_mesh,
)
from weldcell.hal.sim.workpiece_model import SEAM_SPACING, Workpiece, rad


def v_groove_butt(
    length: float = 0.5,
    width: float = 0.15,
    thickness: float = 0.01,
    bevel_angle: float = rad(30),
    root_gap: float = 0.001,
    root_face: float = 0.001,
    seam_spacing: float = SEAM_SPACING,
) -> Workpiece:
    """Two plates butted along x with a single-V groove on top.

    ``width`` is the width of the whole assembly (each plate ``(width - root_gap) / 2``),
    ``bevel_angle`` the bevel of each plate from the vertical (the included angle is twice that),
    ``root_gap`` the opening between the plates and ``root_face`` the height of the unbevelled land.
    Seam ``groove``: the centre of the root opening at the top of the root faces (y = 0, z = root_face)
    along +x, approach straight down (-z). With a root gap the seam is ``root_gap / 2`` from either
    root face (it lies in the opening, where the root pass is aimed).
    """
    kind = "v-groove-butt"
    check_positive(kind, length=length, width=width, thickness=thickness, bevel_angle=bevel_angle)
    check_nonnegative(kind, root_gap=root_gap, root_face=root_face)
    check_spacing(kind, seam_spacing)
    require(
        bevel_angle < rad(80),
        f"{kind}: bevel_angle {math.degrees(bevel_angle):.3g}° is too wide",
        "give bevel_angle in radians below rad(80) (it is per side, from the vertical)",
    )
    require(
        root_face < thickness,
        f"{kind}: root_face {root_face * 1e3:.3g} mm is not below thickness {thickness * 1e3:.3g} mm",
        "give root_face < thickness",
    )
    g2 = root_gap / 2
    top = g2 + (thickness - root_face) * math.tan(bevel_angle)
    require(
        top < width / 2,
        f"{kind}: the groove ({2 * top * 1e3:.3g} mm wide at the top) does not fit in width "
        f"{width * 1e3:.3g} mm",
        "increase width or reduce root_gap / bevel_angle",
    )
    left = np.array(
        [[-width / 2, 0], [-g2, 0], [-g2, root_face], [-top, thickness], [-width / 2, thickness]], dtype=float
    )
    right = left[::-1] * np.array([-1.0, 1.0])  # mirror in y, reverse to stay counter-clockwise
    V, F = merge_parts(
        [extrude_yz(left, -length / 2, length / 2), extrude_yz(right, -length / 2, length / 2)]
    )
    seam = line_seam(
        "groove", "butt", [-length / 2, 0, root_face], [length / 2, 0, root_face], [0, 0, -1], seam_spacing
    )
    params = dict(
        length=length,
        width=width,
        thickness=thickness,
        bevel_angle=bevel_angle,
        root_gap=root_gap,
        root_face=root_face,
        seam_spacing=seam_spacing,
    )
    return Workpiece(kind, kind, triangle_mesh(V, F), [seam], params)


def fillet_t(
    length: float = 0.3,
    base_width: float = 0.2,
    web_height: float = 0.1,
    thickness: float = 0.01,
    web_thickness: float | None = None,
    seam_spacing: float = SEAM_SPACING,
) -> Workpiece:
    """A T joint: a web (``web_thickness``, default ``thickness``) standing centred on a base plate.

    Seams ``fillet-1`` (the +y side of the web) and ``fillet-2`` (the -y side), both along +x, at the
    corner between the web face and the base top; approach bisects the two faces, pointing into the
    corner: (0, -1, -1)/√2 and (0, +1, -1)/√2.
    """
    kind = "fillet-t"
    tw = thickness if web_thickness is None else web_thickness
    check_positive(
        kind,
        length=length,
        base_width=base_width,
        web_height=web_height,
        thickness=thickness,
        web_thickness=tw,
    )
    check_spacing(kind, seam_spacing)
    require(
        tw < base_width,
        f"{kind}: web_thickness {tw * 1e3:.3g} mm does not fit on base_width {base_width * 1e3:.3g} mm",
        "give web_thickness < base_width",
    )
    b, t, h = base_width / 2, thickness, web_height
    poly = np.array(
        [[-b, 0], [b, 0], [b, t], [tw / 2, t], [tw / 2, t + h], [-tw / 2, t + h], [-tw / 2, t], [-b, t]],
        dtype=float,
    )
    V, F = extrude_yz(poly, -length / 2, length / 2)
    s2 = 1 / math.sqrt(2)
    seams = [
        line_seam(
            "fillet-1",
            "fillet",
            [-length / 2, tw / 2, t],
            [length / 2, tw / 2, t],
            [0, -s2, -s2],
            seam_spacing,
        ),
        line_seam(
            "fillet-2",
            "fillet",
            [-length / 2, -tw / 2, t],
            [length / 2, -tw / 2, t],
            [0, s2, -s2],
            seam_spacing,
        ),
    ]
    params = dict(
        length=length,
        base_width=base_width,
        web_height=web_height,
        thickness=thickness,
        web_thickness=tw,
        seam_spacing=seam_spacing,
    )
    return Workpiece(kind, kind, triangle_mesh(V, F), seams, params)


def lap(
    length: float = 0.3,
    width: float = 0.15,
    thickness: float = 0.006,
    overlap: float = 0.04,
    seam_spacing: float = SEAM_SPACING,
) -> Workpiece:
    """A lap joint: an upper plate (+y side) lying on a lower plate (-y side), overlapping by ``overlap``.

    Both plates are ``width`` wide and ``thickness`` thick; the assembly is centred on y = 0, so the
    upper plate's edge is at y = -overlap/2. Seam ``lap``: that edge against the lower plate's top
    surface (z = thickness), along +x; approach bisects the edge face and the lower top: (0, 1, -1)/√2.
    """
    kind = "lap"
    check_positive(kind, length=length, width=width, thickness=thickness, overlap=overlap)
    check_spacing(kind, seam_spacing)
    require(
        overlap < width,
        f"{kind}: overlap {overlap * 1e3:.3g} mm is not less than the plate width {width * 1e3:.3g} mm",
        "give overlap < width",
    )
    total = 2 * width - overlap
    yl0, yl1 = -total / 2, -total / 2 + width
    yu0, yu1 = total / 2 - width, total / 2
    t = thickness
    poly = np.array(
        [[yl0, 0], [yl1, 0], [yl1, t], [yu1, t], [yu1, 2 * t], [yu0, 2 * t], [yu0, t], [yl0, t]], dtype=float
    )
    V, F = extrude_yz(poly, -length / 2, length / 2)
    s2 = 1 / math.sqrt(2)
    seam = line_seam("lap", "lap", [-length / 2, yu0, t], [length / 2, yu0, t], [0, s2, -s2], seam_spacing)
    params = dict(length=length, width=width, thickness=thickness, overlap=overlap, seam_spacing=seam_spacing)
    return Workpiece(kind, kind, triangle_mesh(V, F), [seam], params)


def corner(
    length: float = 0.3,
    width: float = 0.15,
    thickness: float = 0.01,
    seam_spacing: float = SEAM_SPACING,
) -> Workpiece:
    """An outside corner joint (full-open corner): two plates at 90° touching along one edge.

    In the L's own section one plate lies flat and the other hangs from it; their edge faces leave a
    90° V-shaped notch on the outside of the corner. The L is turned 45° about x so the notch opens
    upward (flat welding position): the plates form a roof resting on their far edges on z = 0.
    Seam ``corner``: the bottom of the notch (where the plates touch), along +x, approach -z (the
    bisector of the two edge faces).
    """
    kind = "corner"
    check_positive(kind, length=length, width=width, thickness=thickness)
    check_spacing(kind, seam_spacing)
    require(
        thickness < width,
        f"{kind}: thickness {thickness * 1e3:.3g} mm is not less than width {width * 1e3:.3g} mm",
        "give thickness < width",
    )
    w, t = width, thickness
    plate_h = np.array([[0, -t], [w, -t], [w, 0], [0, 0]], dtype=float)  # (u, v), counter-clockwise
    plate_v = np.array([[-t, -t - w], [0, -t - w], [0, -t], [-t, -t]], dtype=float)
    corner_uv = np.array([0.0, -t])
    a = rad(-45)
    Rm = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])

    def to_yz(p: np.ndarray) -> np.ndarray:
        return (p - corner_uv) @ Rm.T  # rotation keeps counter-clockwise order

    ph, pv = to_yz(plate_h), to_yz(plate_v)
    z0 = min(ph[:, 1].min(), pv[:, 1].min())
    shift = np.array([0.0, -z0])
    V, F = merge_parts(
        [extrude_yz(ph + shift, -length / 2, length / 2), extrude_yz(pv + shift, -length / 2, length / 2)]
    )
    zc = shift[1]
    seam = line_seam("corner", "corner", [-length / 2, 0, zc], [length / 2, 0, zc], [0, 0, -1], seam_spacing)
    params = dict(length=length, width=width, thickness=thickness, seam_spacing=seam_spacing)
    return Workpiece(kind, kind, triangle_mesh(V, F), [seam], params)
