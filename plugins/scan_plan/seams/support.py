"""The plane the part rests on or is held against (a table, a fixture plate), and its contact lines.

Where a part touches a table the two surfaces meet in a concave crease exactly like a fillet root; a
contact line is not a weld seam unless the user says so (``SeamSettings.contact_seams``). The
supporting plane is found from the cloud (:func:`support_plane`): the largest plane (RANSAC, Open3D's
``segment_plane``) that has everything else on one side of it -- *in front of it*, on the sensor's
side: a scan cannot show a part behind the plane it rests on. A part's own face is never that plane
while the table or fixture is in the scan: the part's other surfaces, or the table, lie behind it.
Seam nodes at a contact with it (one side of their crease is the plane: the part's contact lines with
it, or with a fixture plate a few mm behind the part) are dropped (:func:`on_support`,
:func:`drop_contact`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: a RANSAC inlier belongs to the plane's surface when its normal is within this angle of the plane's
PLANE_NORMAL_ANGLE = np.deg2rad(25.0)
#: at most this many planes are tried, largest first
MAX_PLANES = 4
#: a plane holds at least this fraction of the cloud to be a candidate support
MIN_FRACTION = 0.08
#: at most this fraction of the points off a support plane may lie behind it: the slab's own edge faces
#: (a 20 mm fixture plate's rim: 8 % in case 11 of the evaluation set), noise, stray returns
MAX_BEHIND = 0.15
#: a support holds the part when at least this share of the part's points, pushed out by the margin, lie
#: within the plane's points (tables and fixtures of the evaluation set: 0.58-1.0; a lap's lower plate
#: 0.06-0.11: the upper plate reaches beyond it)
SURROUND = 0.5
#: ... and its contact lines are dropped when it reaches beyond the part on every side: at least this share
#: of the corners of the part's outline (pushed out by the margin) lie within the plane's points. Tables and
#: fixtures of the evaluation set: 0.35-0.97 (the part's shadow hides some of the table, a fixture is seen
#: in part); lone plates, one-sided the wrong way or a base plate with nothing under it: the T-joint of
#: profiles/cell1-fillet-sim.toml 0.08, the CLI tests' V-groove 0.12, the demo's V-groove 0.20
ENCLOSE = 0.3
#: a support that encloses at least this share of the part's outline corners is a table or fixture beyond
#: doubt: every lone plate measured passing for a support enclosed less (0.12-0.46: one-sided the wrong way,
#: its groove walls taken for "the part"), tables and fixtures 0.28-1.0. Only below it may the stage re-read
#: a seamless cloud without the plane (``SupportPlane.ambiguous``, ``pipeline.extract_seams``)
UNAMBIGUOUS_ENCLOSE = 0.5
#: a seam node is at a contact when at least this share of the points around it lie on the support plane
#: (a contact crease: about half; a V-groove root on the table, seen through its root gap: a few %)
CONTACT_SHARE = 0.3


@dataclass(frozen=True)
class SupportPlane:
    """``normal . x = offset`` with ``normal`` facing the part (the sensor's side); ``inliers`` its
    points (indices), ``rms`` their RMS distance from it (m), ``tol`` the band (m) within which a seam
    node counts as lying on it, ``surrounds`` / ``encloses`` the shares of the part's points / outline
    corners within its points (:func:`support_plane`)."""

    normal: np.ndarray
    offset: float
    inliers: np.ndarray
    rms: float
    tol: float
    surrounds: float = 1.0
    encloses: float = 1.0

    @property
    def holds_part(self) -> bool:
        """Whether the plane reaches beyond the part on every side (:data:`ENCLOSE` of the part's
        outline within its points): a table or fixture, whose contact lines are not seams -- not a
        T-joint's base plate, which its web reaches the ends of."""
        return self.encloses >= ENCLOSE

    @property
    def ambiguous(self) -> bool:
        """Whether the plane could be a lone plate's face read from the wrong side (it encloses less than
        :data:`UNAMBIGUOUS_ENCLOSE` of the part's outline): the orientation it gives is then a guess."""
        return self.encloses < UNAMBIGUOUS_ENCLOSE

    def distance(self, X: np.ndarray) -> np.ndarray:
        """Signed distances (m) of points ``X`` (n, 3) from the plane (positive in front)."""
        return np.asarray(X, dtype=float) @ self.normal - self.offset


def support_plane(
    P: np.ndarray, N: np.ndarray, noise: float, spacing: float, margin: float, seed: int = 0
) -> SupportPlane | None:
    """The supporting plane of the cloud ``P`` (module docstring), oriented towards the part, or None.

    ``N``: the points' unit normals (their signs do not matter): the plane's points are the RANSAC
    inliers whose normal is within :data:`PLANE_NORMAL_ANGLE` of the plane's (not the bottom rows of
    the walls standing on it).

    ``noise`` (m): the cloud's noise level (RANSAC inlier band ``3 noise``, at least half the point
    ``spacing``, m). A point more than 3 bands from a candidate plane is off it. A support has at least
    1 % of the cloud off it and at most :data:`MAX_BEHIND` of those on one side (the slab's own edge
    faces): its normal faces the other side, where the part is. And it holds the part: at least
    :data:`SURROUND` of the part's points, pushed ``margin`` (m) further out from the part's centre
    within the plane, still lie within the plane's points (a table or fixture reaches beyond the part;
    a lap joint's upper plate, with the lower one stepping down beyond its edge, is one-sided too --
    the wrong way -- but does not reach beyond the lower plate), and reaches beyond it on every side:
    at least :data:`ENCLOSE` of the corners of the part's pushed outline lie within it (a lone
    V-groove plate, one-sided the wrong way with its groove's walls behind it, holds the walls but not
    the groove's ends, which run to the plate's edges). Of several, the largest. Needs no
    normals: a scan cannot show a part behind the plane it rests on, so the side
    the part is on is the sensor's side.
    """
    import open3d as o3d
    from weldcell.sdk.repeatable import open3d_serial

    band = max(3.0 * noise, 0.5 * spacing)
    o3d.utility.random.seed(seed)
    left = np.arange(len(P))
    best = None
    for _ in range(MAX_PLANES):
        if len(left) < MIN_FRACTION * len(P):
            break
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P[left]))
        # one thread: repeatable draws (threaded RANSAC differed between processes at ~1e-4 in the normal);
        # same time on this 2-core host (0.024 s / 0.12 s at 30k / 150k points, threaded or not)
        with open3d_serial():
            (a, b, c, dd), inl = pc.segment_plane(band, 3, 500)
        inl = left[np.asarray(inl, dtype=np.int64)]
        left = np.setdiff1d(left, inl, assume_unique=True)
        n = np.array([a, b, c], dtype=float)
        s = float(np.linalg.norm(n))
        n, off = n / s, -dd / s
        inl = inl[np.abs(N[inl] @ n) >= np.cos(PLANE_NORMAL_ANGLE)]
        if len(inl) < MIN_FRACTION * len(P):
            continue
        dist = P @ n - off
        front, behind = dist > 3.0 * band, dist < -3.0 * band
        if behind.sum() > front.sum():
            n, off, dist, front, behind = -n, -off, -dist, behind, front
        nf = int(front.sum())
        if nf < 0.01 * len(P) or behind.sum() > MAX_BEHIND * (nf + behind.sum()):
            continue
        share, corners = _surrounds(P[inl], P[front], n, margin)
        if share >= SURROUND and corners >= ENCLOSE and (best is None or len(inl) > len(best[2])):
            best = (n, off, inl, float(np.sqrt(np.mean(dist[inl] ** 2))), share, corners)
    if best is None:
        return None
    n, off, inl, rms, share, corners = best
    return SupportPlane(n, off, inl, rms, max(4.0 * rms, 0.75 * spacing), share, corners)


def _surrounds(plane_pts: np.ndarray, part: np.ndarray, n: np.ndarray, margin: float) -> tuple[float, float]:
    """How far the convex hull of ``plane_pts`` (projected on the plane of normal ``n``) holds the
    ``part`` points pushed ``margin`` away from the part's centre: the share of those points inside it,
    and the share of the part's own convex-hull corners inside it (1.0 when the plane reaches beyond
    the part on every side)."""
    from scipy.spatial import ConvexHull, QhullError

    u = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    B = np.column_stack([u, v])
    q = part @ B
    away = q - q.mean(axis=0)
    q = q + margin * away / np.maximum(np.linalg.norm(away, axis=1, keepdims=True), 1e-12)
    try:
        hull = ConvexHull(plane_pts @ B)
        corners = ConvexHull(q).vertices
    except (QhullError, ValueError):  # degenerate (collinear) points: holds nothing
        return 0.0, 0.0
    inside = np.all(q @ hull.equations[:, :2].T + hull.equations[:, 2] <= 0.0, axis=1)
    return float(inside.mean()), float(inside[corners].mean())


def on_support(P: np.ndarray, tree, plane: SupportPlane | None, X: np.ndarray, radius: float) -> np.ndarray:
    """Mask (n,) of the points ``X`` at a contact with ``plane``: within ``plane.tol`` of it and with
    at least :data:`CONTACT_SHARE` of the cloud points within ``radius`` on it (one side of their crease
    is the plane; a V-groove's root on a table has its two bevels as sides, not the table)."""
    if plane is None or not len(X):
        return np.zeros(len(X), dtype=bool)
    near = np.abs(plane.distance(X)) <= max(plane.tol, 0.5 * radius)
    out = np.zeros(len(X), dtype=bool)
    i = np.flatnonzero(near)
    if not len(i):
        return out
    member = np.zeros(len(P) + 1, dtype=bool)
    member[plane.inliers] = True
    d, j = tree.query(X[i], k=min(64, len(P)), distance_upper_bound=radius, workers=-1)
    inside = np.isfinite(d)
    share = (member[np.where(inside, j, len(P))] & inside).sum(1) / np.maximum(inside.sum(1), 1)
    out[i] = share >= CONTACT_SHARE
    return out


def contact_roots(
    P: np.ndarray, N: np.ndarray, idx: np.ndarray, plane: SupportPlane
) -> tuple[np.ndarray, np.ndarray]:
    """Signs of the normals of the part's points beside its contact with ``plane``, from the geometry of
    the contact: indices into ``P`` and +-1 per index (flip ``N`` by it).

    Where a part meets the table or fixture it rests on, the plane's visible points beside the contact lie
    outside the part, so *in front of* the part's face there: a face standing on the table (normal across
    it), a ramp, and an overhanging face that makes an acute wedge with the table (normal 90-180 deg from
    the table's) alike. The sign of the plane's points' mean offset along a part point's normal is
    therefore its orientation. An acute wedge is where sign propagation along normals
    (:func:`~.orientation.propagate_signs`) fails: its points' normals blend into the direction across
    the wedge, 20-25 deg from the table's and 155-160 deg from the overhanging face's, so a parent-to-child
    sign rule (``n_i . n_j >= 0``) flips the whole face, and every face reached through it (evaluation
    set: fillet-T joints resting on their two plate edges, structured light, cases 112, 147, 212, 213).

    ``idx`` (n, k): each point's nearest neighbours. A point counts when it is not a plane point, lies
    off the plane's band (``plane.tol``) but within its neighbourhood's radius of the plane (beside the
    contact, not a face high above a plane seen through a root gap), is steep (normal >= 45 deg from the
    plane's: a shallower face meets the plane at >= 135 deg, where propagation holds), has plane points
    among its neighbours across the contact line from it (not along it: at a corner of the part's footprint
    the plane beside the next face runs on behind this one), all of them more than the plane's noise (3 x
    its inlier RMS) on one side and their mean too (a thin plate's face also has the plane beyond its other
    face, behind it, within reach). Fewer such points than one neighbourhood (k) are no contact line:
    none are returned."""
    member = np.zeros(len(P), dtype=bool)
    member[plane.inliers] = True
    on = member[idx]
    h = plane.distance(P)
    reach = np.linalg.norm(P[idx[:, -1]] - P, axis=1)  # the neighbourhood's radius
    # beside the contact: off the plane's band, but within the neighbourhood's reach of the plane (not a
    # face high above a plane seen through a root gap); and steep (normal >= 45 deg from the plane's):
    # shallower faces meet the plane at >= 135 deg, where the sign propagation holds
    steep = np.abs(N @ plane.normal) < np.cos(np.pi / 4)
    rows = np.flatnonzero(~member & (h > plane.tol) & (h < reach) & steep & on.any(axis=1))
    if not len(rows):
        return rows, np.zeros(0)
    D = P[idx[rows]] - P[rows, None, :]
    off = np.einsum("ikj,ij->ik", D, N[rows])
    # only plane points across the contact line from the point (beside its own face): at a corner of the
    # part's footprint the plane beside the next face runs on behind this face's plane
    line = np.cross(N[rows], plane.normal)
    line /= np.maximum(np.linalg.norm(line, axis=1, keepdims=True), 1e-12)
    on = on[rows] & (np.abs(np.einsum("ikj,ij->ik", D, line)) < np.abs(off))
    keep = on.any(axis=1)
    rows, off, on = rows[keep], off[keep], on[keep]
    mean = np.where(on, off, 0.0).sum(axis=1) / on.sum(axis=1)
    band = 3.0 * plane.rms
    # every plane neighbour on one side: a thin plate's face also has the table beyond its other face
    # (behind it) among its neighbours
    agree = np.all(~on | (off * np.sign(mean)[:, None] > band), axis=1)
    sure = agree & (np.abs(mean) > band)
    if sure.sum() < idx.shape[1]:  # fewer than one neighbourhood's worth: stray points, no contact line
        return rows[:0], np.zeros(0)
    return rows[sure], np.where(mean[sure] > 0, 1.0, -1.0)


def drop_contact(
    P: np.ndarray, tree, seams: list, plane: SupportPlane, radius: float, min_length: float
) -> list:
    """The seams (:class:`~.model.SeamPolyline`) without their nodes at a contact with ``plane``
    (:func:`on_support` within ``radius``): a seam cut there keeps its runs of at least ``min_length``
    (m) as open seams; ids renumbered in order."""
    from .model import SeamPolyline

    out: list[SeamPolyline] = []
    for s in seams:
        keep = ~on_support(P, tree, plane, s.points, radius)
        if keep.all():
            out.append(s)
            continue
        X, A = s.points, s.normals
        if s.closed:  # start the ring at a dropped node so that no kept run wraps around
            k = int(np.argmin(keep))
            X, A, keep = np.roll(X, -k, axis=0), np.roll(A, -k, axis=0), np.roll(keep, -k)
        edges = np.flatnonzero(np.diff(np.r_[0, keep.astype(np.int8), 0]))
        for a, b in zip(edges[::2], edges[1::2], strict=True):
            if b - a < 2:
                continue
            length = float(np.linalg.norm(np.diff(X[a:b], axis=0), axis=1).sum())
            if length >= min_length:
                out.append(SeamPolyline(0, s.joint_class, X[a:b].copy(), A[a:b].copy(), False, length))
    for i, s in enumerate(out):
        s.id = i
    return out
