"""Growing open pieces along their joint beyond their ends (the crease traced step by step on the
cloud) until they meet another piece, the cloud ends or the crease fades."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

from .chaining import _end_directions, _Piece
from .model import BEHIND_TOL, _unit
from .refinement import _refine_nodes
from .sides import _fit_two_planes, _sides_at


@dataclass(frozen=True)
class _Tracer:
    """The cloud and the settings of :func:`grow_pieces` (one object instead of a dozen arguments)."""

    P: np.ndarray
    N: np.ndarray
    tree: cKDTree
    spacing: float
    eps: float
    side_radius: float
    approach_radius: float
    min_crease_angle: float
    max_steps: int
    max_turn: float
    max_approach_turn: float
    max_join_angle: float


@dataclass(frozen=True)
class Growing:
    """Settings of :func:`grow_pieces` (lengths in m, angles in rad)."""

    spacing: float  # step between traced nodes
    eps: float  # a trace this close to another piece's end joins it
    side_radius: float  # radius of the side-plane fits of every traced node
    approach_radius: float  # radius of their approach fits
    min_crease_angle: float  # smallest crease angle a traced node must show
    max_length: float  # longest trace per end
    max_turn: float = np.deg2rad(30.0)  # largest turn of one step
    max_approach_turn: float = np.deg2rad(20.0)  # largest turn of the approach in one step
    max_join_angle: float = np.deg2rad(45.0)  # approaches of a trace and the piece it joins agree within


def grow_pieces(
    P: np.ndarray,
    N: np.ndarray,
    tree: cKDTree,
    pieces: list[_Piece],
    settings: Growing | None = None,
    **overrides: float,
) -> list[_Piece]:
    """Extend every open piece at both ends by tracing its joint (seam tracking on the cloud), and join
    the pieces the traces run into.

    ``settings`` is a :class:`Growing`; keyword ``overrides`` replace its fields (or give them all, e.g.
    ``grow_pieces(P, N, tree, pieces, spacing=0.0015, eps=0.003, ..., max_length=0.3)``).

    Where a shallow crease (e.g. the flanks of a pipe junction, ~145 deg included angle) gives too few
    eq. 16 edge points, a seam is found in pieces. From each open end, nodes are placed ``spacing``
    further along the end direction and snapped onto the two side planes (:func:`_refine_nodes`); a node
    is accepted while the fit is a concave crease of at least ``min_crease_angle`` with surface on both
    sides (:func:`_refine_on_sides`), the cloud continues around it (its neighbours within
    ``side_radius`` are not all behind it: the part or the scan ends there), the step turns by less
    than ``max_turn`` and the approach by less than ``max_approach_turn``, at most ``max_length`` (m)
    per end. A trace that comes within ``eps`` of another piece's end (approaches within
    ``max_join_angle``) joins that piece; one that reaches its own piece's other end closes it into a
    loop; one that meets any other node stops. Closed pieces are returned unchanged.
    """
    c = replace(settings, **overrides) if settings is not None else Growing(**overrides)
    max_steps = int(c.max_length / c.spacing)
    if max_steps < 1:
        return pieces
    tr = _Tracer(
        P,
        N,
        tree,
        c.spacing,
        c.eps,
        c.side_radius,
        c.approach_radius,
        c.min_crease_angle,
        max_steps,
        c.max_turn,
        c.max_approach_turn,
        c.max_join_angle,
    )
    out = [_with_fit(p) for p in pieces]
    todo = [(i, e) for i, p in enumerate(out) if not p.closed for e in (0, 1)]
    while todo:
        i, e = todo.pop(0)
        j = _grow_end(tr, out, i, e)
        if j is not None:  # out[-1] is piece i (traced end last) + piece j: both new ends are traced again
            keep = [k for k in range(len(out) - 1) if k not in (i, j)]
            renumber = {k: n for n, k in enumerate(keep)}
            out = [out[k] for k in keep] + [out[-1]]
            todo = [(renumber[k], f) for k, f in todo if k in renumber] + [
                (len(out) - 1, 0),
                (len(out) - 1, 1),
            ]
    return out


def _with_fit(p: _Piece) -> _Piece:
    """``p`` with its ``ok`` / ``crease`` arrays filled in (all usable / 0 where not refined)."""
    ok = p.ok if p.ok is not None else np.ones(len(p.X), dtype=bool)
    crease = p.crease if p.crease is not None else np.zeros(len(p.X))
    return _Piece(p.X, p.A, p.closed, p.labels, ok, crease)


def _sub(p: _Piece, sl: slice, closed: bool | None = None) -> _Piece:
    """The nodes ``sl`` of ``p`` (reversed order with a negative step), optionally re-flagged closed."""
    return _Piece(p.X[sl], p.A[sl], p.closed if closed is None else closed, p.labels, p.ok[sl], p.crease[sl])


def _concat(a: _Piece, b: _Piece) -> _Piece:
    """The open run of ``a``'s nodes followed by ``b``'s."""
    return _Piece(
        np.vstack([a.X, b.X]),
        np.vstack([a.A, b.A]),
        False,
        a.labels + b.labels,
        np.concatenate([a.ok, b.ok]),
        np.concatenate([a.crease, b.crease]),
    )


def _blocking_nodes(out: list[_Piece], i: int, X: np.ndarray, end_len: float) -> tuple[np.ndarray, ...]:
    """Nodes a trace from the end of ``X`` (piece ``i``, traced end last) must stop at: every other
    piece's, and ``X``'s own beyond ``end_len`` of its end. Returns (owner, index, points)."""
    owner, index, nodes = [], [], []
    for j, p in enumerate(out):
        Xj = X if j == i else p.X
        sel = np.arange(len(Xj))
        if j == i:
            sel = sel[np.linalg.norm(Xj - Xj[-1], axis=1) >= end_len]
        owner.append(np.full(len(sel), j))
        index.append(sel)
        nodes.append(Xj[sel])
    return np.concatenate(owner), np.concatenate(index), np.vstack(nodes)


def _grow_end(tr: _Tracer, out: list[_Piece], i: int, e: int) -> int | None:
    """Trace end ``e`` (0 start, 1 end) of ``out[i]`` (:func:`grow_pieces`) and store the longer piece
    in ``out[i]`` (closed when the trace reached its own other end). When the trace ran into the end of
    piece j, the join (piece i, traced end last, then piece j) is appended to ``out`` and j returned."""
    piece = out[i] if e == 1 else _sub(out[i], slice(None, None, -1))
    end_len = 3.0 * tr.eps
    owner, index, nodes = _blocking_nodes(out, i, piece.X, end_len)
    grown, A, crease, hit = _trace_joint(tr, piece.X, piece.A, nodes)
    if len(grown):
        n = len(grown)
        piece = _concat(
            piece, _Piece(grown, A, False, np.zeros(6, dtype=np.int64), np.ones(n, dtype=bool), crease)
        )
    joined = None
    if hit >= 0:
        j, k = int(owner[hit]), int(index[hit])
        other = piece if j == i else out[j]
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(other.X, axis=0), axis=1))])
        d_end = _unit(piece.X[-1] - piece.X[-3])
        if j == i and s[k] <= end_len:  # reached its own other end: a loop, without overlap where it closes
            piece = _sub(piece, slice(_first_ahead(piece.X[: k + 1], piece.X[-1], d_end), None), closed=True)
        elif j != i and min(s[k], s[-1] - s[k]) <= end_len:
            tail = (
                other if s[k] <= s[-1] - s[k] else _sub(other, slice(None, None, -1))
            )  # end it ran into first
            a_end, a_tail = _unit(piece.A[-3:].mean(axis=0)), _unit(tail.A[:3].mean(axis=0))
            if float(a_end @ a_tail) >= np.cos(tr.max_join_angle):
                n_end = int(np.sum(np.linalg.norm(tail.X - tail.X[0], axis=1) <= end_len + tr.eps))
                start = _first_ahead(tail.X[:n_end], piece.X[-1], d_end)  # its nodes behind the trace: off
                joined = (j, _sub(tail, slice(start, None)))
    out[i] = piece if e == 1 else _sub(piece, slice(None, None, -1))
    if joined is None:
        return None
    out.append(_concat(piece, joined[1]))
    return joined[0]


def _first_ahead(X: np.ndarray, end: np.ndarray, d: np.ndarray) -> int:
    """Index of the first node of ``X`` lying ahead of ``end`` along ``d`` (len(X) when none does)."""
    ahead = np.flatnonzero((X - end) @ d > 0)
    return int(ahead[0]) if len(ahead) else len(X)


def _cloud_ends(tr: _Tracer, x: np.ndarray, d: np.ndarray) -> bool:
    """True where the cloud ends at ``x``: fewer than 6 points within ``tr.side_radius``, or they lie
    behind it along ``d`` on average (no surface ahead of the node)."""
    nb = tr.tree.query_ball_point(x, tr.side_radius)
    return len(nb) < 6 or float(np.mean((tr.P[nb] - x) @ d)) < -0.25 * tr.side_radius


def _crease_direction(tr: _Tracer, x: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Direction (sign of ``d``) of the intersection line of the two side planes fitted around ``x``
    within ``tr.side_radius``; ``d`` where they are nearly parallel."""
    _, valid, na, nb, in_a, Q = _sides_at(tr.P, tr.N, tr.tree, x[None], tr.side_radius, 256)
    na, _, nb, _, _, _, _ = _fit_two_planes(Q, valid, na, nb, in_a, behind_tol=BEHIND_TOL * tr.side_radius)
    u = np.cross(na[0], nb[0])
    if float(np.linalg.norm(u)) < np.sin(tr.min_crease_angle):
        return d
    u = _unit(u)
    return u if float(u @ d) >= 0 else -u


def _trace_joint(
    tr: _Tracer, X: np.ndarray, A: np.ndarray, block: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """The nodes (n, 3), approaches (n, 3) and crease angles (n,) traced beyond the last node of ``X``
    (approaches ``A``; see :func:`grow_pieces`), and the index of the node of ``block`` the trace ran
    into (within ``tr.eps``; -1 when it stopped for another reason)."""
    chord = max(0.01, 3 * tr.spacing)
    d = _end_directions(X, tr.spacing, chord)[1]
    if float(np.linalg.norm(X[-1] - X[0])) < chord:  # a short piece: its chord is no direction
        d = _crease_direction(tr, X[-1], d)
    a = _unit(A[-5:].mean(axis=0))
    pos = X[-1]
    block_tree = cKDTree(block) if len(block) else None
    cos_turn, cos_app = np.cos(tr.max_turn), np.cos(tr.max_approach_turn)
    nodes, apps, creases, hit = [], [], [], -1
    for _ in range(tr.max_steps):
        if _cloud_ends(tr, pos + tr.spacing * d, d):  # the part or the scan ends ahead: no fit needed
            break
        Xn, An, ok, crease = _refine_nodes(
            tr.P,
            tr.N,
            tr.tree,
            (pos + tr.spacing * d)[None],
            tr.side_radius,
            tr.approach_radius,
            tr.min_crease_angle,
        )
        x, an = Xn[0], An[0]
        step = x - pos
        length = float(np.linalg.norm(step))
        if not ok[0] or length < 0.3 * tr.spacing or float(step @ d) < cos_turn * length or an @ a < cos_app:
            break
        if block_tree is not None:
            dist, k = block_tree.query(x)
            if dist < tr.eps:
                hit = int(k)
                break
        if _cloud_ends(tr, x, d):
            break
        nodes.append(x)
        apps.append(an)
        creases.append(float(crease[0]))
        d = _unit(d + step / length)
        a, pos = an, x
    if not nodes:
        return np.empty((0, 3)), np.empty((0, 3)), np.empty(0), hit
    return np.array(nodes), np.array(apps), np.array(creases), hit
