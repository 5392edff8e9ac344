"""Point-to-distribution NDT (Magnusson 2009; paper 004's ref. [33], the registration of its §II-D hand-over
between local maps and of its §II-E relocalization). Pure numerics (numpy, pykdtree): the public home of
NDT for every plugin (plugins/mapping's segment hand-over, plugins/relocalize).

* The target is cut into cubic cells of side ``r``; every cell with at least ``min_points_per_cell``
  points becomes a Gaussian (mean, covariance). Covariances are regularised as in the thesis (§6.2):
  eigenvalues below ``eigenvalue_ratio`` x the largest are raised to it.
* Score of a source point x' against a cell (thesis eq. 6.9, 6.8):
  ``s = -d1 exp(-d2/2 (x'-mu)^T C^-1 (x'-mu))`` with d1, d2 from the outlier ratio and the cell volume.
* Newton's method on the summed score with the analytic gradient and Hessian (thesis eq. 6.12, 6.13),
  a step bounded to the cell size and a backtracking (Armijo) line search; multi-resolution from coarse
  to fine cells. The resolutions are derived from the data (point spacing, extent, initial uncertainty).

Deviation (documented in docs/methods/relocalization.md): the 6 pose parameters are a local increment
``T <- exp(delta) T`` (translation, rotation vector) instead of global Euler angles; the Newton update and
its first/second point derivatives are the same expressions evaluated at delta = 0, without gimbal lock.
A point is scored against its own cell and the 6 face neighbours (the thesis' DIRECT7 lookup).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydantic import Field
from pykdtree.kdtree import KDTree
from weldcell.sdk.errors import DataError
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Length

CHI2_3DOF_99 = 11.345  # 99 % quantile of chi-square with 3 degrees of freedom: a point "fits" its cell


class NDTSettings(Settings):
    """Settings of the NDT registration; every length left at 0 is derived from the data."""

    fine_resolution: Length = Field(0.0, ge=0.0, description="finest cell size (0: from the point spacing)")
    coarse_resolution: Length = Field(
        0.0, ge=0.0, description="coarsest cell size (0: from the initial uncertainty and the extent)"
    )
    points_per_cell: int = Field(
        10, ge=6, description="median points per occupied target cell that sets the fine resolution"
    )
    min_points_per_cell: int = Field(6, ge=4, description="cells with fewer points get no Gaussian (PCL: 6)")
    eigenvalue_ratio: float = Field(0.01, gt=0, lt=1, description="covariance regularisation (thesis §6.2)")
    outlier_ratio: float = Field(0.55, ge=0, lt=1, description="share of outliers in the score mixture")
    k_cells: int = Field(7, description="cells scored per point: 1 (DIRECT1) or 7 (DIRECT7, own + 6 faces)")
    max_iterations: int = Field(30, ge=1, description="Newton iterations per resolution")
    max_source_points: int = Field(2000, ge=100, description="source points used per resolution")
    epsilon: float = Field(
        2e-3, gt=0, description="stop when the step is below epsilon x resolution (m) and epsilon (rad)"
    )


@dataclass
class NDTResult:
    """T_target_source after NDT; ``score`` is the mean best-cell score of a source point (0..1),
    ``overlap`` the share of source points inside the 99 % ellipsoid of a target cell."""

    T: np.ndarray
    score: float
    overlap: float
    iterations: int
    converged: bool
    resolutions: tuple[float, ...]


@dataclass
class CellGrid:
    """The Gaussians of one target at one resolution, found by their voxel key (thesis: direct lookup)."""

    resolution: float
    keys: np.ndarray  # (M,) sorted voxel keys
    means: np.ndarray  # (M, 3)
    inv_cov: np.ndarray  # (M, 3, 3)
    d1: float
    d2: float


_OFF, _SPAN = 1 << 20, 1 << 21  # voxel indices within +-2^20 cells: keys fit in int64


def _key(ijk: np.ndarray) -> np.ndarray:
    ijk = ijk + _OFF
    return (ijk[..., 0] * _SPAN + ijk[..., 1]) * _SPAN + ijk[..., 2]


_DIRECT7 = np.array([[0, 0, 0], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]])


def point_spacing(points: np.ndarray, sample: int = 2000, seed: int = 0) -> float:
    """Median nearest-neighbour distance of a sample of the points."""
    pts = np.asarray(points, dtype=float)
    if len(pts) < 2:
        raise DataError("a cloud needs at least 2 points to measure its spacing", "pass a denser cloud")
    rng = np.random.default_rng(seed)
    q = pts[rng.choice(len(pts), min(sample, len(pts)), replace=False)]
    d, _ = KDTree(pts).query(q, k=2)
    d = d[:, 1][d[:, 1] > 0]
    return float(np.median(d)) if len(d) else 1e-3


def voxel_keys(points: np.ndarray, voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """(inverse, counts): each point's occupied-voxel index and the points per voxel."""
    ijk = np.floor(points / voxel).astype(np.int64)
    ijk -= ijk.min(axis=0)
    dims = ijk.max(axis=0) + 1
    key = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
    _, inv, counts = np.unique(key, return_inverse=True, return_counts=True)
    return inv.ravel(), counts


def voxel_downsample(points: np.ndarray, voxel: float) -> np.ndarray:
    """One point (the mean) per occupied voxel."""
    inv, counts = voxel_keys(points, voxel)
    out = np.zeros((len(counts), 3))
    for c in range(3):
        out[:, c] = np.bincount(inv, weights=points[:, c]) / counts
    return out


def fine_resolution(points: np.ndarray, settings: NDTSettings) -> float:
    """Smallest cell size (from 2 x spacing, grown by the square law of surface samples, at least x1.1)
    whose median occupied cell holds ``points_per_cell`` points: every Gaussian has enough samples."""
    if settings.fine_resolution > 0:
        return float(settings.fine_resolution)
    r = 2.0 * point_spacing(points)
    ext = float(np.max(np.ptp(points, axis=0)))
    while r < ext:
        med = float(np.median(voxel_keys(points, r)[1]))
        if med >= settings.points_per_cell:
            break
        r *= float(np.clip(np.sqrt(settings.points_per_cell / med), 1.1, 2.0))
    return r


def resolution_ladder(
    target: np.ndarray, settings: NDTSettings, uncertainty: float, fine: float | None = None
) -> tuple[float, ...]:
    """Coarse-to-fine cell sizes: the coarse cell covers twice the initial uncertainty (NDT's basin is
    about one cell), limited to a quarter of the target's extent; halved down to the fine size."""
    fine = fine_resolution(target, settings) if fine is None else fine
    ext = float(np.max(np.ptp(target, axis=0)))
    wide = float(np.clip(2.0 * uncertainty, fine, max(fine, ext / 4.0)))
    coarse = settings.coarse_resolution or _snap(wide, fine)
    while not settings.coarse_resolution and coarse > max(fine, ext / 4.0) * 1.001 and coarse > fine * 1.001:
        coarse /= 2.0  # never coarser than a quarter of the target
    out = [coarse]
    while out[-1] / 2.0 > fine * 1.2:
        out.append(out[-1] / 2.0)
    if out[-1] > fine * 1.001:
        out.append(fine)
    return tuple(out)


def _snap(coarse: float, fine: float) -> float:
    """``coarse`` rounded to the nearest ``fine`` x 2^k (k >= 0): every ladder of one target then uses the
    same cell sizes, so a prepared target (:class:`NDT` caches its cells per size) serves every
    uncertainty."""
    k = max(0, int(round(np.log2(max(coarse, fine) / fine))))
    return float(fine * 2.0**k)


def score_constants(resolution: float, outlier_ratio: float) -> tuple[float, float]:
    """d1, d2 of the Gaussian approximation of the mixture (thesis eq. 6.8; PCL's gauss_d1/d2)."""
    c1 = 10.0 * (1.0 - outlier_ratio)
    c2 = outlier_ratio / resolution**3
    d3 = -np.log(c2)
    d1 = -np.log(c1 + c2) - d3
    d2 = -2.0 * np.log((-np.log(c1 * np.exp(-0.5) + c2) - d3) / d1)
    return float(d1), float(d2)


def build_cells(target: np.ndarray, resolution: float, settings: NDTSettings) -> CellGrid:
    """Voxel Gaussians of the target at one resolution (mean, regularised inverse covariance)."""
    ijk = np.floor(target / resolution).astype(np.int64)
    if np.abs(ijk).max() >= _OFF:
        raise DataError(
            f"the target spans more than 2^20 cells of {resolution:.3g} m", "use a larger resolution"
        )
    keys, inv, counts = np.unique(_key(ijk), return_inverse=True, return_counts=True)
    inv = inv.ravel()
    n = counts.astype(float)
    s1 = np.stack([np.bincount(inv, weights=target[:, c]) for c in range(3)], axis=1)
    s2 = np.empty((len(n), 3, 3))
    for a in range(3):
        for b in range(a, 3):
            s2[:, a, b] = s2[:, b, a] = np.bincount(inv, weights=target[:, a] * target[:, b])
    keep = counts >= settings.min_points_per_cell
    if not keep.any():
        raise DataError(
            f"no NDT cell of {resolution:.3g} m holds {settings.min_points_per_cell} target points",
            "the target cloud is too sparse for this resolution; give a denser map or a larger resolution",
        )
    keys, n, s1, s2 = keys[keep], n[keep], s1[keep], s2[keep]
    mu = s1 / n[:, None]
    cov = (s2 - n[:, None, None] * mu[:, :, None] * mu[:, None, :]) / (n[:, None, None] - 1.0)
    w, V = np.linalg.eigh(cov)
    floor = np.maximum(settings.eigenvalue_ratio * w[:, 2:3], (1e-3 * resolution) ** 2)
    w = np.maximum(w, floor)
    inv_cov = np.einsum("mij,mj,mkj->mik", V, 1.0 / w, V)
    d1, d2 = score_constants(resolution, settings.outlier_ratio)
    return CellGrid(resolution, keys, mu, inv_cov, d1, d2)


def _pairs(grid: CellGrid, pts: np.ndarray, k: int):
    """(point, cell) pairs: the point's own cell (k = 1, DIRECT1) or it and its 6 face neighbours (k > 1,
    DIRECT7 of the thesis), where the target has a Gaussian."""
    ijk = np.floor(pts / grid.resolution).astype(np.int64)
    offs = _DIRECT7[: 1 if k == 1 else 7]
    keys = _key(ijk[:, None, :] + offs[None, :, :])  # (N, n_offs)
    pos = np.searchsorted(grid.keys, keys)
    pos = np.minimum(pos, len(grid.keys) - 1)
    ok = grid.keys[pos] == keys
    pi, oi = np.nonzero(ok)
    return pi, pos[pi, oi]


def evaluate(grid: CellGrid, pts: np.ndarray, k: int, derivatives: bool = True):
    """Score (to maximise) of the points ``pts`` (already transformed) and, if asked, its gradient (6,)
    and Hessian (6, 6) with respect to a local increment [t, w] (thesis eq. 6.10-6.13)."""
    pi, ci = _pairs(grid, pts, k)
    if len(pi) == 0:
        return 0.0, np.zeros(6), np.zeros((6, 6)), pi, np.zeros(0)
    p = pts[pi]
    x = p - grid.means[ci]
    C = grid.inv_cov[ci]
    xC = np.matmul(C, x[:, :, None])[:, :, 0]
    q = np.einsum("mi,mi->m", x, xC)
    e = np.exp(-0.5 * grid.d2 * q)
    score = float(-grid.d1 * e.sum())
    if not derivatives:
        return score, None, None, pi, q
    a = np.concatenate([xC, np.cross(p, xC)], axis=1)  # x^T C J  (M, 6)
    J = np.zeros((len(p), 3, 6))
    J[:, 0, 0] = J[:, 1, 1] = J[:, 2, 2] = 1.0
    px, py, pz = p[:, 0], p[:, 1], p[:, 2]  # columns 3..5: e_k x p
    J[:, 1, 3], J[:, 2, 3] = -pz, py
    J[:, 0, 4], J[:, 2, 4] = pz, -px
    J[:, 0, 5], J[:, 1, 5] = -py, px
    w = grid.d1 * grid.d2 * e
    g = (w[:, None] * a).sum(axis=0)
    CJ = np.matmul(C, J)
    JCJ = (J * w[:, None, None]).reshape(-1, 6).T @ CJ.reshape(-1, 6)
    H = -grid.d2 * (a * w[:, None]).T @ a + JCJ
    # x^T C d2p/dw_a dw_b = 1/2 (xC_a p_b + xC_b p_a) - (xC . p) delta_ab
    outer = (xC * w[:, None]).T @ p
    H[3:, 3:] += 0.5 * (outer + outer.T) - np.eye(3) * float(np.sum(w * np.einsum("mi,mi->m", xC, p)))
    return score, g, H, pi, q


def _increment(delta: np.ndarray) -> np.ndarray:
    """exp of the increment [t, w]: rotation by Rodrigues' formula, then translation t."""
    T = np.eye(4)
    w = delta[3:]
    th = float(np.linalg.norm(w))
    K = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if th < 1e-12:
        T[:3, :3] += K
    else:
        T[:3, :3] += np.sin(th) / th * K + (1.0 - np.cos(th)) / th**2 * (K @ K)
    T[:3, 3] = delta[:3]
    return T


def _newton_direction(g: np.ndarray, H: np.ndarray, resolution: float) -> np.ndarray:
    """Ascent direction -H^-1 g with H forced negative definite, bounded to one cell / 0.5 rad."""
    w, V = np.linalg.eigh(-H)
    w = np.maximum(w, 1e-6 * max(float(np.max(np.abs(w))), 1e-12))
    step = V @ ((V.T @ g) / w)
    t, r = np.linalg.norm(step[:3]), np.linalg.norm(step[3:])
    scale = min(1.0, resolution / max(t, 1e-12), 0.5 / max(r, 1e-12))
    return step * scale


def _align_level(grid, src, T, settings):
    """Newton iterations at one resolution; the evaluation at an accepted step is reused by the next one."""
    it, converged = 0, False
    k = settings.k_cells
    s0, g, H, _, _ = evaluate(grid, src @ T[:3, :3].T + T[:3, 3], k)
    for it in range(1, settings.max_iterations + 1):  # noqa: B007
        if not np.any(g):
            break
        d = _newton_direction(g, H, grid.resolution)
        slope, alpha = float(g @ d), 1.0
        while alpha > 1e-3:  # backtracking line search (Armijo)
            Tn = _increment(alpha * d) @ T
            s1, g1, H1, _, _ = evaluate(grid, src @ Tn[:3, :3].T + Tn[:3, 3], k)
            if s1 >= s0 + 1e-4 * alpha * slope:
                break
            alpha *= 0.5
        else:
            converged = True  # no ascent along the Newton direction: a maximum
            break
        T, s0, g, H = Tn, s1, g1, H1
        step = alpha * d
        if (
            np.linalg.norm(step[:3]) < settings.epsilon * grid.resolution
            and np.linalg.norm(step[3:]) < settings.epsilon
        ):
            converged = True
            break
    return T, it, converged


def _sample(src: np.ndarray, voxel: float, n: int, seed: int = 0) -> np.ndarray:
    pts = voxel_downsample(src, voxel)
    if len(pts) > n:
        pts = pts[np.random.default_rng(seed).choice(len(pts), n, replace=False)]
    return pts


def fit_quality(grid: CellGrid, pts: np.ndarray, k: int) -> tuple[float, float]:
    """(score, overlap) of transformed points: mean best-cell exp(-d2 q/2) and share with q < chi2 99 %."""
    _, _, _, pi, q = evaluate(grid, pts, k, derivatives=False)
    best = np.full(len(pts), np.inf)
    np.minimum.at(best, pi, q)
    score = float(np.mean(np.where(np.isfinite(best), np.exp(-0.5 * grid.d2 * best), 0.0)))
    return score, float(np.mean(best < CHI2_3DOF_99))


class NDT:
    """A target prepared once (cells per resolution), registered against many sources/initial guesses."""

    def __init__(self, target: np.ndarray, settings: NDTSettings | None = None) -> None:
        self.settings = settings or NDTSettings()
        self.target = np.asarray(target, dtype=float)
        if len(self.target) < 10 or not np.all(np.isfinite(self.target)):
            raise DataError("the NDT target needs at least 10 finite points", "check the map or cloud file")
        self.fine = fine_resolution(self.target, self.settings)
        self._grids: dict[float, CellGrid] = {}
        self._samples: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}

    def sample(self, source: np.ndarray, resolution: float) -> np.ndarray:
        """The source points scored at ``resolution``: one per half-cell voxel, at most
        ``max_source_points``. The last few samples are kept (the cache holds the source array itself, so its
        identity cannot be reused; a source changed in place between calls is not supported)."""
        key = (id(source), source.shape, round(float(resolution), 9))
        hit = self._samples.get(key)
        if hit is not None and hit[0] is source:
            return hit[1]
        pts = _sample(source, resolution / 2.0, self.settings.max_source_points)
        if len(self._samples) >= 16:
            self._samples.pop(next(iter(self._samples)))
        self._samples[key] = (source, pts)
        return pts

    def grid(self, resolution: float) -> CellGrid:
        key = round(float(resolution), 9)
        if key not in self._grids:
            self._grids[key] = build_cells(self.target, key, self.settings)
        return self._grids[key]

    def ladder(self, uncertainty: float) -> tuple[float, ...]:
        return resolution_ladder(self.target, self.settings, uncertainty, fine=self.fine)

    def quality(
        self, source: np.ndarray, T: np.ndarray, resolution: float | None = None
    ) -> tuple[float, float]:
        src = self.sample(source, resolution or self.fine)
        pts = src @ T[:3, :3].T + T[:3, 3]
        return fit_quality(self.grid(resolution or self.fine), pts, self.settings.k_cells)

    def align(
        self,
        source: np.ndarray,
        T_init: np.ndarray | None = None,
        uncertainty: float | None = None,
        resolutions: tuple[float, ...] | None = None,
    ) -> NDTResult:
        """Register ``source`` to the target from ``T_init``; ``uncertainty`` (m) of the initial guess sets
        the coarsest resolution (default: 4 x the fine resolution)."""
        source = np.asarray(source, dtype=float)
        if len(source) < 10 or not np.all(np.isfinite(source)):
            raise DataError("the NDT source needs at least 10 finite points", "check the cloud file")
        T = np.eye(4) if T_init is None else np.asarray(T_init, dtype=float).copy()
        levels = resolutions or self.ladder(uncertainty if uncertainty is not None else 2.0 * self.fine)
        total, converged = 0, False
        for r in levels:
            src = self.sample(source, r)
            T, it, converged = _align_level(self.grid(r), src, T, self.settings)
            total += it
        score, overlap = self.quality(source, T, levels[-1])
        return NDTResult(T, score, overlap, total, converged, tuple(levels))


def ndt_align(
    target: np.ndarray,
    source: np.ndarray,
    T_init: np.ndarray | None = None,
    settings: NDTSettings | None = None,
    uncertainty: float | None = None,
) -> NDTResult:
    """One-shot NDT: ``T_target_source`` registering ``source`` onto ``target``."""
    return NDT(target, settings).align(source, T_init, uncertainty)
