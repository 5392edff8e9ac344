"""Relocalization against a prior map (paper 004 §II-E, eq. 6): Γ = [τx, τy, τz, θx, θy, θz].

Initial guesses (§II-E): the magnetometer's yaw θz and GNSS's position τ (through ENU) when given; the
prior's key-frame positions (or, for plain clouds, a grid over the prior map) as position hypotheses when
no GNSS exists; several yaw hypotheses when the yaw is missing or uncertain. The hypotheses are ranked by
their NDT score at the coarse resolution, the best are registered by NDT coarse to fine and the three best
refined at the fine resolution (§II-E: "three high-resolution poses"; by small-gicp GICP by default, the
most accurate in benchmarks/relocalize.py, or by ``method``). Without any prior (and when a prior
does not verify) global registration (FPFH + RANSAC) gives the initial guess.

Better than the paper: every answer is verified. ``overlap`` (share of the current points inside the 99 %
ellipsoid of a prior-map cell at the fine resolution) must reach ``min_overlap`` and no distinct solution
may come within ``ambiguity_margin`` of it; otherwise the result is ``failed`` with the reason.
Maps are assumed gravity-aligned (z up, as from visual-inertial odometry): the hypotheses vary yaw only,
NDT then refines all six parameters.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from pydantic import Field
from scipy.spatial.transform import Rotation
from weldcell.sdk.registration.ndt import NDT, NDTSettings, point_spacing, voxel_downsample
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Angle

from .global_reg import GlobalSettings, derive_voxel, ransac
from .global_reg import features as global_features
from .local_reg import refine

SCHEMA = "weldcell/relocalization@1"


class RelocalizeSettings(Settings):
    """Settings of the relocalization (thresholds justified in docs/methods/relocalization.md)."""

    method: str = Field(
        "gicp",
        description="fine registration after NDT's coarse levels: gicp (small-gicp, the benchmark's winner), "
        "vgicp, ndt or icp (Open3D point-to-plane)",
    )
    min_overlap: float = Field(0.9, gt=0, le=1, description="verified when this share of current points fits")
    ambiguity_margin: float = Field(0.05, ge=0, le=1, description="a distinct solution this close: ambiguous")
    yaw_step: Angle = Field(math.radians(30.0), gt=0, description="spacing of yaw hypotheses")
    candidates: int = Field(6, ge=3, description="hypotheses registered coarse to fine after ranking")
    global_attempts: int = Field(
        6, ge=1, description="RANSAC runs (other seeds; features made once) before global registration fails"
    )
    refine_margin: float = Field(
        0.2,
        ge=0,
        le=1,
        description="of the three best, a pose whose overlap before the fine level trails the best by more "
        "than this is not refined (the fine level moves overlap by a few %; it stays a rival as it is)",
    )
    ndt: NDTSettings = Field(
        default_factory=NDTSettings,
        description="P2D NDT (sdk.registration.ndt): resolutions, outlier ratio, steps",
    )
    global_reg: GlobalSettings = Field(
        default_factory=GlobalSettings,
        description="FPFH + RANSAC global registration when the priors do not verify",
    )


@dataclass
class Priors:
    """Initial-guess sources in the prior map's frame: the current map's heading (rad) and the position of
    its origin (m), each with a 1-sigma uncertainty; ``keyframe_positions`` of the prior map (N, 3)."""

    yaw: float | None = None
    yaw_sigma: float = math.radians(5.0)
    position: np.ndarray | None = None
    position_sigma: float = 2.0
    keyframe_positions: np.ndarray | None = None


@dataclass
class RelocalizationResult:
    """``weldcell/relocalization@1``: T_prior_current maps current-map coordinates into the prior map."""

    status: str
    T_prior_current: np.ndarray
    score: float
    overlap: float
    confidence: float
    priors_used: list[str]
    seconds: float
    method: str
    reason: str | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def gamma(self) -> np.ndarray:
        """Eq. (6): [τx, τy, τz, θx, θy, θz] (m, rad; θ as x-y-z fixed-axis roll, pitch, yaw)."""
        T = self.T_prior_current
        return np.concatenate([T[:3, 3], Rotation.from_matrix(T[:3, :3]).as_euler("xyz")])

    def to_json(self) -> dict:
        def num(x: float) -> float:
            return float(x) if np.isfinite(x) else 0.0

        out = {
            "schema": SCHEMA,
            "status": self.status,
            "T_prior_current": [[num(v) for v in row] for row in self.T_prior_current],
            "gamma": [num(v) for v in self.gamma],
            "score": num(self.score),
            "overlap": num(self.overlap),
            "confidence": num(self.confidence),
            "priors_used": list(self.priors_used),
            "method": self.method,
            "seconds": num(self.seconds),
            "notes": list(self.notes),
        }
        if self.reason:
            out["reason"] = self.reason
        return out


@dataclass
class _Solution:
    T: np.ndarray
    score: float
    overlap: float
    source: str


def _yaw_T(yaw: float, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", yaw).as_matrix()
    T[:3, 3] = t
    return T


def _yaws(priors: Priors, step: float) -> list[float]:
    if priors.yaw is None:
        return list(np.arange(0.0, 2 * math.pi - 1e-9, step))
    half = min(3.0 * priors.yaw_sigma, math.pi)
    if half <= step / 2:
        return [priors.yaw]
    n = int(math.ceil(2 * half / step))
    return list(priors.yaw + np.linspace(-half, half, n + 1)[: n if half >= math.pi else n + 1])


def _positions(prior: np.ndarray, current: np.ndarray, priors: Priors, spacing: float, widen: bool = False):
    """Translation hypotheses as (t for yaw 0 placement of the current centroid): the GNSS position, else the
    prior key-frame positions, else a grid over the prior map's occupied area at ``spacing``."""
    if priors.position is not None:  # GNSS height is its weakest axis: also the grounds matched
        p = np.asarray(priors.position, float)
        if not widen:
            return [("position", p), ("position-ground", p)]
        sig = priors.position_sigma
        offs = [np.array([dx, dy, 0.0]) for dx in (-sig, 0, sig) for dy in (-sig, 0, sig) if dx or dy]
        return [(k, p + o) for o in offs for k in ("position", "position-ground")]
    if priors.keyframe_positions is not None and len(priors.keyframe_positions):
        return [("keyframe", p) for p in np.asarray(priors.keyframe_positions, float)]
    xy = _cells(prior, spacing)
    return [("grid", np.array([(i + 0.5) * spacing, (j + 0.5) * spacing, np.nan])) for i, j in xy]


def _ground(prior: np.ndarray) -> float:
    key = (id(prior), prior.shape, "ground")
    hit = _CELLS.get(key)
    if hit is None or hit[0] is not prior:
        hit = _CELLS[key] = (prior, float(np.percentile(prior[:, 2], 5)))
    return hit[1]


_CELLS: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}


def _cells(prior: np.ndarray, spacing: float) -> np.ndarray:
    """Occupied (x, y) cells of the prior map at ``spacing`` (kept for the last few maps and spacings)."""
    key = (id(prior), prior.shape, round(spacing, 9))
    hit = _CELLS.get(key)
    if hit is None or hit[0] is not prior:
        if len(_CELLS) >= 8:
            _CELLS.pop(next(iter(_CELLS)))
        hit = _CELLS[key] = (prior, np.unique(np.floor(prior[:, :2] / spacing).astype(np.int64), axis=0))
    return hit[1]


def _hypotheses(
    prior, current, priors, s: RelocalizeSettings, spacing: float, widen: bool = False
) -> list[tuple[str, np.ndarray]]:
    out = []
    c = current.mean(axis=0)
    zc, zp = (
        np.percentile(current[:, 2], 5),
        _ground(prior),
    )  # ground heights (gravity-aligned)
    for yaw in _yaws(priors, s.yaw_step):
        R = Rotation.from_euler("z", yaw).as_matrix()
        for kind, p in _positions(prior, current, priors, spacing, widen):
            if kind in ("position", "keyframe"):  # the current map's origin at that position (§II-E)
                t = p
            elif kind == "position-ground":
                t = np.array([p[0], p[1], zp - (R @ [0, 0, zc])[2]])
            else:  # the current map's centroid at the grid cell, its ground on the prior's ground
                t = np.array([p[0], p[1], 0.0]) - R @ c
                t[2] = zp - (R @ [0, 0, zc])[2]
            out.append((kind, _yaw_T(yaw, t)))
    return out


class PriorMap:
    """A prior map prepared once when it is loaded, then relocalized against many times: its NDT (cells per
    resolution, made on first use and kept), point spacing, KD-tree, ground height and small-gicp targets.
    :meth:`warm` makes the cells and targets of a relocalization ahead of time (the robot loads the prior
    map before it needs it)."""

    def __init__(self, points: np.ndarray, ndt_settings: NDTSettings | None = None) -> None:
        from pykdtree.kdtree import KDTree

        t0 = time.perf_counter()
        self.points = np.asarray(points, dtype=float)
        self.ndt = NDT(self.points, ndt_settings)
        self.spacing = point_spacing(self.points)
        self.tree = KDTree(self.points)
        self.ground = float(np.percentile(self.points[:, 2], 5))
        self.prepare_seconds = time.perf_counter() - t0
        self._global: dict[float, tuple] = {}

    def global_features(self, voxel: float) -> tuple:
        """The map's FPFH features at ``voxel`` for global registration (made once per voxel, kept)."""
        key = round(voxel, 9)
        if key not in self._global:
            self._global[key] = global_features(self.points, voxel)
        return self._global[key]

    def warm(self, settings: RelocalizeSettings | None = None, uncertainties=(2.0,)) -> PriorMap:
        """Build the NDT cells of the ladders for these uncertainties (m) and the fine small-gicp target."""
        from .local_reg import gicp_target

        s = settings or RelocalizeSettings()
        t0 = time.perf_counter()
        for u in (*uncertainties, float(np.max(np.ptp(self.points[:, :2], axis=0))) / 4.0):
            for r in self.ndt.ladder(max(u, self.ndt.fine)):
                self.ndt.grid(r)
        if s.method in ("gicp", "vgicp"):
            gicp_target(self.ndt, self.ndt.fine, s.method)
        self.prepare_seconds += time.perf_counter() - t0
        return self


class _Checker:
    """The fit of the current map at a pose: NDT score at the fine resolution and ``overlap``, the share of
    current points (one per ``delta`` voxel) within ``delta`` of a prior-map point. ``delta`` = 2.5 x the
    coarser of the two median point spacings, or 1.25 x the distance to the 4th current neighbour where the
    current cloud is sparser: a point on a surface both maps sampled lies within about one spacing
    of a prior sample; a point on structure that is not in the prior map (another site, a wrong pose) does
    not. Tighter than NDT's 99 % ellipsoid, whose cells are several spacings wide.

    The overlap is the lower of two shares: of all sampled points, and of the *structure* points (whose
    surface normal is more than 45 deg from the current map's vertical: walls, boxes, pipes). The ground
    fits almost anywhere and can carry a wrong pose past the threshold on its own (Table IV at n = 100: a
    GNSS-only pose 1.85 m / 3.2 deg off fitted 94 % of all points but only 79 % of the structure points);
    structure is what fixes x, y and yaw. With fewer than ``MIN_STRUCTURE`` structure points the share of all
    points is used alone (the ambiguity check then guards a featureless scene)."""

    MIN_STRUCTURE = 20

    def __init__(self, prior: PriorMap, current: np.ndarray, sampled: np.ndarray) -> None:
        from pykdtree.kdtree import KDTree

        self.ndt = prior.ndt
        self.delta = 2.5 * max(prior.spacing, point_spacing(current))
        self.tree = prior.tree
        self.current = sampled
        self.sample = voxel_downsample(current, self.delta)
        # where the current cloud is sparser (LiDAR far range), the bound follows its local spacing
        tree = KDTree(current)
        local, _ = tree.query(self.sample, k=4)
        self.bound = np.maximum(self.delta, 1.25 * local[:, -1])
        self.structure = _structure(current, tree, self.sample)
        if self.structure.sum() < self.MIN_STRUCTURE:
            self.structure = None

    def fit(self, T: np.ndarray) -> tuple[float, float]:
        score, _ = self.ndt.quality(self.current, T)
        d, _ = self.tree.query(self.sample @ T[:3, :3].T + T[:3, 3], k=1)
        inside = d <= self.bound
        share = float(np.mean(inside))
        if self.structure is not None:
            share = min(share, float(np.mean(inside[self.structure])))
        return score, share


def _structure(current: np.ndarray, tree, sample: np.ndarray, k: int = 10) -> np.ndarray:
    """Mask of the ``sample`` points on non-horizontal surfaces: the normal of their ``k`` nearest
    ``current`` points (smallest principal axis) more than 45 deg from the vertical. (k = 10 marks the
    same share as 16 on the Table IV visits, 33 %, in 2/3 of the time.)"""
    _, idx = tree.query(sample, k=min(k, len(current)))
    nb = current[np.asarray(idx).reshape(len(sample), -1)]
    c = nb - nb.mean(axis=1, keepdims=True)
    _, vec = np.linalg.eigh(c.transpose(0, 2, 1) @ c)
    return np.abs(vec[:, 2, 0]) < math.cos(math.radians(45.0))


def _distinct(a: np.ndarray, b: np.ndarray, dist: float) -> bool:
    E = np.linalg.inv(a) @ b
    return np.linalg.norm(E[:3, 3]) > dist or Rotation.from_matrix(E[:3, :3]).magnitude() > math.radians(5)


def _search(chk: _Checker, current, hyps, uncertainty: float, s: RelocalizeSettings) -> list[_Solution]:
    """Rank hypotheses by their coarse score, register the best coarse-to-fine, refine three at fine."""
    ndt = chk.ndt
    levels = ndt.ladder(uncertainty)
    coarse = levels[0]
    if len(hyps) > s.candidates:
        ranked = sorted(hyps, key=lambda h: -ndt.quality(current, h[1], coarse)[0])
        hyps = ranked[: s.candidates]
    mid = levels[:-1] or levels  # NDT's wide basin at the coarse cells
    # successive halving: every candidate at the coarsest cells, the better half (at least 3) further
    first = [(kind, refine(ndt, current, T0, mid[:1], "ndt")) for kind, T0 in hyps]
    first.sort(key=lambda h: -ndt.quality(current, h[1], mid[0])[0])
    keep = max(3, (len(first) + 1) // 2)
    sols = [_Solution(T, *chk.fit(T), kind) for kind, T in first[keep:]]  # still rivals in the verdict
    for kind, T in first[:keep]:
        if len(mid) > 1:
            T = refine(ndt, current, T, mid[1:], "ndt")
        sols.append(_Solution(T, *chk.fit(T), kind))
    sols.sort(key=lambda x: -x.score)
    final = []
    top = max(x.overlap for x in sols[:3])
    rest = list(sols[3:])
    for sol in sols[:3]:  # §II-E: the three best refined at high resolution (distinct poses only)
        if any(not _distinct(f.T, sol.T, ndt.fine) for f in final):
            continue
        if final and sol.overlap < top - s.refine_margin:  # cannot become a rival: kept as it is
            rest.append(sol)
            continue
        T = refine(ndt, current, sol.T, levels[-1:], s.method)
        final.append(_Solution(T, *chk.fit(T), sol.source))
    return sorted(final, key=lambda x: -x.overlap) + rest


def _global(chk: _Checker, pm: PriorMap, current, s: RelocalizeSettings) -> list[_Solution]:
    """FPFH + RANSAC, then NDT and the fine method: the features of both maps once (the prior map's kept
    in ``pm``), one RANSAC run per attempt with another seed until one verifies."""
    ndt = chk.ndt
    sols = []
    # the voxel keeps the *current* map at <= max_points (it sets RANSAC's cost); the larger prior map is
    # sampled at the same voxel (more points, features made once per map): at the voxel that keeps the
    # whole 40 x 30 m prior at 3000 points, 3 of 73 trials without priors found no pose in 3 seeds
    voxel = s.global_reg.voxel or max(derive_voxel(current, current, s.global_reg.max_points), 2 * pm.spacing)
    ft = pm.global_features(voxel)
    fs = global_features(current, voxel)
    for attempt in range(s.global_attempts):
        g = ransac(ft, fs, voxel, s.global_reg.model_copy(update={"seed": s.global_reg.seed + attempt}))
        lad = ndt.ladder(2.0 * g.voxel)
        src = chk.current  # the registrations use the current map sampled once
        T = refine(ndt, src, refine(ndt, src, g.T, lad[:-1] or lad, "ndt"), lad[-1:], s.method)
        sols.append(_Solution(T, *chk.fit(T), "global"))
        if sols[-1].overlap >= s.min_overlap:
            break
    return sorted(sols, key=lambda x: -x.overlap)


def _verdict(sols: list[_Solution], s: RelocalizeSettings, fine: float) -> tuple[bool, float, str | None]:
    best = sols[0]
    if best.overlap < s.min_overlap:
        return (
            False,
            0.0,
            (
                f"only {best.overlap:.0%} of the current map fits the prior map "
                f"(at least {s.min_overlap:.0%} "
                "needed): another site, a changed scene, or a wrong initial guess"
            ),
        )
    rivals = [x.overlap for x in sols[1:] if _distinct(best.T, x.T, 2.0 * fine)]
    second = max(rivals, default=0.0)
    if second >= best.overlap - s.ambiguity_margin:
        return (
            False,
            0.0,
            (
                f"ambiguous: two distinct poses fit {best.overlap:.0%} and {second:.0%} of the current map "
                "(a repetitive or symmetric scene); give a position or heading prior"
            ),
        )
    conf = (best.overlap - s.min_overlap) / (1 - s.min_overlap + 1e-9)
    conf *= min(1.0, (best.overlap - second) / max(best.overlap - s.min_overlap * 0.5, 1e-9))
    return True, float(np.clip(0.5 + 0.5 * conf, 0.5, 1.0)), None


def prepare(prior: np.ndarray | PriorMap, settings: RelocalizeSettings | None = None) -> PriorMap:
    """The prior map prepared for these settings (``prior`` itself when it already is, with the same NDT
    settings)."""
    s = settings or RelocalizeSettings()
    if isinstance(prior, PriorMap) and prior.ndt.settings == s.ndt:
        return prior
    return PriorMap(prior.points if isinstance(prior, PriorMap) else prior, s.ndt)


def relocalize(
    prior: np.ndarray | PriorMap,
    current: np.ndarray,
    priors: Priors | None = None,
    settings: RelocalizeSettings | None = None,
) -> RelocalizationResult:
    """Find T_prior_current (eq. 6) from the priors given; verified, else ``status == "failed"``.
    ``prior`` is a cloud (N, 3) or a :class:`PriorMap` prepared once per loaded map (faster)."""
    t0 = time.perf_counter()
    s = settings or RelocalizeSettings()
    pr = priors or Priors()
    pm = prepare(prior, s)
    prior = pm.points
    ndt = pm.ndt
    current = np.asarray(current, dtype=float)
    # the current map once at a quarter of the fine cell: every NDT level samples at >= half a cell and
    # small-gicp downsamples at a quarter; the verification keeps the full cloud
    full = current
    chk = _Checker(pm, full, voxel_downsample(full, ndt.fine / 4.0))
    current = chk.current
    used, notes, sols = [], [], []
    ok, conf, reason = False, 0.0, None
    if pr.yaw is not None:
        used.append("yaw")
    if pr.position is not None:
        used.append("position")
    if pr.position is None and pr.keyframe_positions is not None and len(pr.keyframe_positions):
        used.append("keyframes")
    if used and (pr.yaw is not None or pr.position is not None):
        extent = float(np.max(np.ptp(current[:, :2], axis=0)))
        unc = pr.position_sigma if pr.position is not None else max(ndt.fine, extent / 4.0)
        spacing = max(unc, ndt.fine) if pr.position is None else 0.0
        hyps = _hypotheses(prior, current, pr, s, spacing)
        sols = _search(chk, current, hyps, max(unc, ndt.fine), s)
        ok, conf, reason = _verdict(sols, s, ndt.fine)
        if not ok and pr.position is not None:  # second pass: positions over +-1 sigma of the GNSS fix
            hyps = _hypotheses(prior, current, pr, s, 0.0, widen=True)
            sols = sorted(sols + _search(chk, current, hyps, max(unc, ndt.fine), s), key=lambda x: -x.overlap)
            ok, conf, reason = _verdict(sols, s, ndt.fine)
        if not ok:
            notes.append(
                f"the priors ({', '.join(used)}) did not verify: {reason}; trying global registration"
            )
    if not sols or not ok:
        gl = _global(chk, pm, full, s)
        sols = sorted(gl + sols, key=lambda x: -x.overlap)
        if sols[0].source == "global":
            used = ["global"] + [u for u in used if u != "keyframes"]
        ok, conf, reason = _verdict(sols, s, ndt.fine)
    rejected = [u for u in used if ok and _contradicts(u, sols[0].T, pr)]
    if rejected:  # e.g. a magnetometer disturbed by steel: the verified map match contradicts it
        notes.append(f"rejected prior(s) inconsistent with the verified map match: {', '.join(rejected)}")
        used = [u for u in used if u not in rejected]
    best = sols[0]
    return RelocalizationResult(
        "ok" if ok else "failed",
        best.T,
        best.score,
        best.overlap,
        conf if ok else 0.0,
        used,
        time.perf_counter() - t0,
        s.method,
        reason,
        notes,
    )


def _contradicts(kind: str, T: np.ndarray, pr: Priors) -> bool:
    """Whether the verified pose lies outside 3 sigma (plus 2 deg / 10 cm) of a prior."""
    if kind == "yaw" and pr.yaw is not None:
        yaw = Rotation.from_matrix(T[:3, :3]).as_euler("ZYX")[0]
        return abs((yaw - pr.yaw + math.pi) % (2 * math.pi) - math.pi) > 3 * pr.yaw_sigma + math.radians(2)
    if kind == "position" and pr.position is not None:
        return float(np.linalg.norm(T[:3, 3] - pr.position)) > 3 * pr.position_sigma + 0.1
    return False
