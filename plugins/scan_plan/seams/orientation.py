"""Normal orientation from the scan's own geometry, when no camera position was recorded.

A scan shows the outside of what it saw, so every measured normal faces the sensor side. Without the
sensor's position that side is recovered from the cloud (:func:`scan_side_normals`):

1. the scan's main viewing axis, up to its sign;
2. its sign: a scan cannot show a part behind the table it rests on or the fixture plate it is held
   against, so the side of the supporting plane (:func:`~.support.support_plane`) the part lies on is
   the sensor's side, and that plane's normal is the axis. (Seen orthographically, a part on a table
   and the same points seen from behind the table are the same picture; the support is what tells
   them apart.) Without a support in the scan (a lone plate), the axis is the principal axis of the
   normals, signed so that the points facing along it lie in front of the cloud's centroid (a plate's
   face in front of the walls of its groove) -- a guess that a V-groove and a ridge share;
3. the points whose normal is within :data:`RELIABLE_ANGLE` of that axis take its sign; every other
   normal takes its sign through the minimum spanning tree of the neighbour graph weighted
   ``1 - |n_i . n_j|`` (Hoppe et al. 1992: the sign travels along the smoothest paths, not across
   creases), rooted at the reliable points -- and at the part's steep faces beside the support's contact,
   which take their sign from the contact's geometry (:func:`~.support.contact_roots`: the plane beside
   a face lies in front of it). Propagation alone flips a face that overhangs the support: across an acute
   wedge the blended normals turn by less than 90 deg per step while the faces' turn by more.

Nothing is assumed about where "up" is, where the camera was or how the part is placed.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import breadth_first_order, minimum_spanning_tree

from ..cloud_numerics import largest_eigvec
from .support import SupportPlane, contact_roots

#: normals within this angle of the viewing axis take their sign from it directly: a surface facing
#: away from the sensor by more than 180 - 25 deg cannot be seen from a view cone narrower than ~60 deg
RELIABLE_ANGLE = np.deg2rad(25.0)


def viewing_axis(N: np.ndarray) -> np.ndarray:
    """Principal axis (unit, sign arbitrary) of unoriented normals ``N`` (n, 3)."""
    C = (N.T @ N / max(len(N), 1))[None]
    return largest_eigvec(C)[0]


def sensor_side(P: np.ndarray, N: np.ndarray, support: SupportPlane | None) -> np.ndarray:
    """Unit vector from the scanned surface towards the sensor's side: the support plane's normal
    (towards the part resting on it) when there is one; else the principal axis of the normals ``N``,
    signed so that the points facing along it lie in front of the cloud's centroid (a plate's face in
    front of the walls of its groove)."""
    if support is not None:
        return support.normal
    d = viewing_axis(N)
    facing = np.abs(N @ d) >= np.cos(RELIABLE_ANGLE)
    ref = P[facing] if facing.sum() >= 3 else P
    return d if float(np.mean((ref - P.mean(axis=0)) @ d)) >= 0 else -d


def propagate_signs(
    N: np.ndarray, idx: np.ndarray, d: np.ndarray, roots: tuple[np.ndarray, np.ndarray] | None = None
) -> np.ndarray:
    """``N`` flipped to a consistent orientation: points within :data:`RELIABLE_ANGLE` of ``+-d`` face
    ``+d``; the points ``roots[0]`` (optional, e.g. :func:`~.support.contact_roots`) take the signs
    ``roots[1]`` (+-1, applied to their normal) unless they are reliable already; the others take the sign
    of their parent along the minimum spanning tree of the neighbour graph ``idx`` (n, k) with weights
    ``1 - |n_i . n_j|``, rooted at those points. Points the graph does not connect to any of them face
    ``+d`` (their normal's sign towards it)."""
    n = len(N)
    cos_d = N @ d
    reliable = np.abs(cos_d) >= np.cos(RELIABLE_ANGLE)
    given = np.zeros(n)  # +-1 at the extra roots
    if roots is not None and len(roots[0]):
        given[roots[0]] = roots[1]
        given[reliable] = 0.0
    i = np.repeat(np.arange(n), idx.shape[1])
    j = idx.reshape(-1)
    keep = i != j
    i, j = i[keep], j[keep]
    w = 1.0 - np.abs(np.einsum("ij,ij->i", N[i], N[j])) + 1e-6
    root = n
    r = np.flatnonzero(reliable | (given != 0))
    rows = np.concatenate([i, np.full(len(r), root)])
    cols = np.concatenate([j, r])
    wts = np.concatenate([w, np.full(len(r), 1e-9)])
    G = coo_matrix((wts, (rows, cols)), shape=(n + 1, n + 1)).tocsr()
    G = G.maximum(G.T)
    T = minimum_spanning_tree(G)
    order, pred = breadth_first_order(T, root, directed=False, return_predecessors=True)
    sign = np.where(cos_d >= 0, 1.0, -1.0)  # unreached points and the reliable ones
    reached = np.zeros(n + 1, dtype=bool)
    reached[order] = True
    reached[root] = False
    child = np.flatnonzero(reached[:n])
    parent = pred[child]
    rel = np.ones(n + 1)
    from_root = parent == root
    top = child[from_root]
    rel[top] = np.where(given[top] != 0, given[top], np.where(cos_d[top] >= 0, 1.0, -1.0))
    inner = child[~from_root]
    rel[inner] = np.where(np.einsum("ij,ij->i", N[inner], N[pred[inner]]) >= 0, 1.0, -1.0)
    # the product of the relative signs along each path to the root (pointer doubling)
    up = np.full(n + 1, root)
    up[child] = parent
    acc = rel.copy()
    for _ in range(64):
        if np.all(up[child] == root):
            break
        acc[child] = acc[child] * acc[up[child]]
        up[child] = up[up[child]]
    sign[child] = acc[child]
    return N * sign[:, None]


def scan_side_normals(
    P: np.ndarray, N: np.ndarray, idx: np.ndarray, support: SupportPlane | None, contact: bool = True
) -> np.ndarray:
    """Unoriented unit normals ``N`` of the points ``P`` oriented towards the scan's sensor side, from
    the cloud alone (module docstring); ``idx`` (n, k) neighbour indices of each point, ``support`` the
    plane the part rests on (:func:`~.support.support_plane`) when the scan holds one. ``contact``: the
    part's faces beside the support take their signs from the contact (:func:`~.support.contact_roots`);
    the pipeline turns it off on line scans, whose neighbourhoods reach across 5-7 mm between lines, wider
    than the contact zone they test (evaluation set, line laser: the roots' signs came out mixed, 41 vs 24
    on case 222, which lost its seam)."""
    roots = None if support is None or not contact else contact_roots(P, N, idx, support)
    return propagate_signs(N, idx, sensor_side(P, N, support), roots)
