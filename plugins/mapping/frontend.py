"""Visual front end (paper 004 §II-B): ORB features, matching, RANSAC PnP with depth, triangulation.

A :class:`FrameFeatures` holds one image's ORB key points and descriptors and, where the registered
depth image has a value, each key point's 3-D position in the camera frame (eq. 3 back-projection).
:func:`relative_pose` matches two frames (Hamming k-NN with Lowe's ratio test) and solves the pose
of the current camera in the reference camera with ``cv2.solvePnPRansac`` on the reference's 3-D
points, refined by Levenberg-Marquardt on the inliers. :func:`triangulate` is eq. (4): 3-D points
from two views with a known relative pose, for features whose depth is missing.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from weldcell.hal.readings import Intrinsics


@dataclass
class FrameFeatures:
    """ORB features of one colour image: pixels (N, 2), descriptors (N, 32) uint8, points (N, 3)
    in the camera frame (NaN where the depth is missing or out of range)."""

    pixels: np.ndarray
    descriptors: np.ndarray
    points: np.ndarray
    octaves: np.ndarray | None = None
    """(N,) ORB pyramid level of each key point (None: level 0); its pixel sigma is 1.2^octave."""

    @property
    def n_with_depth(self) -> int:
        return int(np.isfinite(self.points[:, 2]).sum()) if len(self.points) else 0


@dataclass
class PnPResult:
    """The pose of the current camera in the reference camera (``T_ref_cur``) and its support."""

    T_ref_cur: np.ndarray | None
    matches: int
    inliers: int
    rmse_px: float
    inlier_idx: np.ndarray
    """(K, 2) indices (reference, current) of the inlier matches."""
    sigma_r: float = float("nan")
    """1-sigma rotation (rad) from the reprojection Jacobian: rmse^2 (J^T J)^-1."""
    sigma_t: float = float("nan")
    """1-sigma translation (m), same source."""

    @property
    def ok(self) -> bool:
        return self.T_ref_cur is not None


SEARCH_RADIUS = 0.03
"""Guided matching window, as a fraction of the image width (19 px at 640 px): the prediction from the
IMU between key frames is good to a few pixels."""
MAX_HAMMING = 80
"""Largest descriptor distance of a guided match (of 256 bits; ORB-SLAM uses 50-100)."""
SEARCH_CANDIDATES = 12
"""At most this many current features (nearest to the projection) are compared per reference point."""


class OrbFrontEnd:
    """ORB extraction + matching + PnP with the settings of :class:`~.settings.FrontEndSettings`."""

    def __init__(self, settings) -> None:
        self.s = settings
        self.orb = cv2.ORB_create(
            nfeatures=settings.n_features, scaleFactor=1.2, nlevels=8, fastThreshold=settings.fast_threshold
        )
        self.matcher = cv2.BFMatcher(cv2.NORM_HAMMING)

    def extract(self, rgb: np.ndarray, depth: np.ndarray | None, K: Intrinsics) -> FrameFeatures:
        """ORB on the grey image; 3-D points from the registered depth (eq. 3) where it is valid."""
        gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY) if rgb.ndim == 3 else rgb
        kps, desc = self.orb.detectAndCompute(gray, None)
        if desc is None or not kps:
            return FrameFeatures(np.zeros((0, 2)), np.zeros((0, 32), np.uint8), np.zeros((0, 3)))
        px = np.array([k.pt for k in kps], dtype=np.float64)
        octv = np.array([k.octave for k in kps], dtype=np.int16)
        pts = np.full((len(px), 3), np.nan)
        if depth is not None:
            u = np.clip(np.round(px[:, 0]).astype(int), 0, depth.shape[1] - 1)
            v = np.clip(np.round(px[:, 1]).astype(int), 0, depth.shape[0] - 1)
            z = depth[v, u].astype(np.float64)
            ok = np.isfinite(z) & (z > 0) & (z <= self.s.max_depth)
            pts[ok, 0] = (px[ok, 0] - K.cx) * z[ok] / K.fx
            pts[ok, 1] = (px[ok, 1] - K.cy) * z[ok] / K.fy
            pts[ok, 2] = z[ok]
        return FrameFeatures(px, desc, pts, octv)

    def match(self, ref: FrameFeatures, cur: FrameFeatures) -> np.ndarray:
        """(M, 2) index pairs (ref, cur) passing Lowe's ratio test, one per current feature."""
        if len(ref.descriptors) < 2 or len(cur.descriptors) < 2:
            return np.zeros((0, 2), int)
        knn = self.matcher.knnMatch(cur.descriptors, ref.descriptors, k=2)
        pairs = [
            (m[0].trainIdx, m[0].queryIdx)
            for m in knn
            if len(m) == 2 and m[0].distance < self.s.ratio * m[1].distance
        ]
        if not pairs:
            return np.zeros((0, 2), int)
        pairs = np.array(pairs, int)
        _, first = np.unique(pairs[:, 0], return_index=True)  # one current feature per reference one
        return pairs[np.sort(first)]

    def match_guided(self, ref: FrameFeatures, cur: FrameFeatures, K: Intrinsics, T_ref_cur) -> np.ndarray:
        """(M, 2) index pairs (ref, cur): each reference point with depth is projected into the current
        image with the predicted pose ``T_ref_cur`` and compared only with the current features within
        ``search_radius`` (a fraction of the image width) — ORB-SLAM's search by projection: the cost is
        linear in the features instead of quadratic, and far fewer wrong matches. Lowe's ratio among
        the candidates, one reference point per current feature."""
        from scipy.spatial import cKDTree

        idx_r = np.flatnonzero(np.isfinite(ref.points[:, 2]))
        if len(idx_r) < 2 or len(cur.pixels) < 2:
            return np.zeros((0, 2), int)
        T = np.linalg.inv(T_ref_cur)
        P = ref.points[idx_r] @ T[:3, :3].T + T[:3, 3]
        front = P[:, 2] > 0.05
        idx_r, P = idx_r[front], P[front]
        uv = np.column_stack([K.fx * P[:, 0] / P[:, 2] + K.cx, K.fy * P[:, 1] / P[:, 2] + K.cy])
        k = min(SEARCH_CANDIDATES, len(cur.pixels))
        dist, nn = cKDTree(cur.pixels).query(uv, k=k, distance_upper_bound=SEARCH_RADIUS * K.width)
        ok = np.isfinite(dist.reshape(len(uv), -1))
        if not ok.any():
            return np.zeros((0, 2), int)
        qi = np.nonzero(ok)[0]
        cj = nn.reshape(len(uv), -1)[ok].astype(int)
        da = np.ascontiguousarray(ref.descriptors[idx_r[qi]]).view(np.uint64)
        db = np.ascontiguousarray(cur.descriptors[cj]).view(np.uint64)
        d = np.bitwise_count(np.bitwise_xor(da, db)).sum(1, dtype=np.int32)
        order = np.lexsort((d, qi))
        qi, cj, d = qi[order], cj[order], d[order]
        first = np.flatnonzero(np.r_[True, qi[1:] != qi[:-1]])
        second_d = np.full(len(first), 256)
        has2 = np.r_[first[1:], len(qi)] - first > 1
        second_d[has2] = d[first[has2] + 1]
        best = first[(d[first] < self.s.ratio * second_d) & (d[first] <= MAX_HAMMING)]
        pairs = np.column_stack([idx_r[qi[best]], cj[best]])
        pairs = pairs[np.argsort(d[best], kind="stable")]
        _, keep = np.unique(pairs[:, 1], return_index=True)  # one reference point per current feature
        return pairs[np.sort(keep)]

    def relative_pose(
        self,
        ref: FrameFeatures,
        cur: FrameFeatures,
        K: Intrinsics,
        T_guess: np.ndarray | None = None,
        guided: bool = True,
    ) -> PnPResult:
        """RANSAC PnP of the current frame against the reference's 3-D points (``T_ref_cur``). With a
        guess (the IMU prediction) the matches are searched by projection, else by brute force (also
        when the guided search finds too few)."""
        m = np.zeros((0, 2), int)
        if T_guess is not None and guided:
            m = self.match_guided(ref, cur, K, T_guess)
        if len(m) < 2 * self.s.min_inliers:
            m = self.match(ref, cur)
        if len(m):
            m = m[np.isfinite(ref.points[m[:, 0], 2])]
        empty = PnPResult(None, len(m), 0, float("nan"), np.zeros((0, 2), int))
        if len(m) < self.s.min_inliers:
            return empty
        obj = ref.points[m[:, 0]].astype(np.float64)
        img = cur.pixels[m[:, 1]].astype(np.float64)
        Km = K.K
        use_guess = T_guess is not None
        rvec0 = tvec0 = None
        if use_guess:
            T_cur_ref = np.linalg.inv(T_guess)
            rvec0 = cv2.Rodrigues(T_cur_ref[:3, :3])[0]
            tvec0 = T_cur_ref[:3, 3].reshape(3, 1).copy()
        ok, rvec, tvec, inl = cv2.solvePnPRansac(
            obj,
            img,
            Km,
            None,
            rvec=rvec0,
            tvec=tvec0,
            useExtrinsicGuess=use_guess,
            iterationsCount=self.s.ransac_iterations,
            reprojectionError=self.s.reprojection_px,
            confidence=0.999,
            flags=cv2.SOLVEPNP_ITERATIVE if use_guess else cv2.SOLVEPNP_EPNP,
        )
        if not ok or inl is None or len(inl) < self.s.min_inliers:
            return PnPResult(None, len(m), 0 if inl is None else len(inl), float("nan"), empty.inlier_idx)
        inl = inl.ravel()
        C = self._point_covariances(ref, cur, m[inl], obj[inl], K)
        rvec, tvec, cov, rmse = weighted_refine(obj[inl], img[inl], Km, rvec, tvec, C)
        if cov is not None:
            sr, st = float(np.sqrt(np.trace(cov[:3, :3]) / 3)), float(np.sqrt(np.trace(cov[3:, 3:]) / 3))
        else:
            sr = st = float("nan")
        T_cur_ref = np.eye(4)
        T_cur_ref[:3, :3] = cv2.Rodrigues(rvec)[0]
        T_cur_ref[:3, 3] = tvec.ravel()
        return PnPResult(np.linalg.inv(T_cur_ref), len(m), len(inl), rmse, m[inl], sr, st)

    def _point_covariances(self, ref: FrameFeatures, cur: FrameFeatures, m: np.ndarray, obj: np.ndarray, K):
        """Per match, the pixel sigma of the current key point (1.2^octave, ORB's pyramid) and the 3-D
        covariance of the reference point: stereo depth noise sigma_z = depth_noise * z^2 along the ray
        (the camera's model) and the reference key point's own pixel sigma across it. Returns
        ``(sigma_px (M,), Sigma_P (M, 3, 3))``."""

        def level_sigma(f: FrameFeatures, idx: np.ndarray) -> np.ndarray:
            if f.octaves is None:
                return np.ones(len(idx))
            return 1.2 ** f.octaves[idx].astype(float)

        s_cur = level_sigma(cur, m[:, 1])
        s_ref = level_sigma(ref, m[:, 0])
        z = obj[:, 2]
        ray = obj / np.linalg.norm(obj, axis=1, keepdims=True)
        s_lat = s_ref * z / K.fx
        s_z = self.s.depth_noise * z**2
        Sig = s_lat[:, None, None] ** 2 * (np.eye(3)[None] - ray[:, :, None] * ray[:, None, :])
        Sig += (s_z**2)[:, None, None] * ray[:, :, None] * ray[:, None, :]
        return s_cur, Sig


def weighted_refine(obj, img, Km, rvec, tvec, C, iterations: int = 5):
    """Gauss-Newton refinement of a PnP pose with each point's own 2x2 covariance (pixel noise plus
    the 3-D point's covariance projected into the image) and a Huber kernel; returns rvec, tvec, the
    6x6 covariance of (rvec, tvec) and the reprojection RMSE (px)."""
    s_px, Sig = C
    rvec, tvec = rvec.reshape(3, 1).astype(float), tvec.reshape(3, 1).astype(float)
    cov = None
    for _ in range(iterations):
        proj, jac = cv2.projectPoints(obj, rvec, tvec, Km, None)
        r = (img - proj.reshape(-1, 2)).reshape(-1, 2)
        J = jac[:, :6].reshape(-1, 2, 6)
        R = cv2.Rodrigues(rvec)[0]
        Pc = obj @ R.T + tvec.ravel()
        x, y, zc = Pc[:, 0], Pc[:, 1], Pc[:, 2]
        fx, fy = Km[0, 0], Km[1, 1]
        Jp = np.zeros((len(obj), 2, 3))
        Jp[:, 0, 0], Jp[:, 0, 2] = fx / zc, -fx * x / zc**2
        Jp[:, 1, 1], Jp[:, 1, 2] = fy / zc, -fy * y / zc**2
        JpR = Jp @ R
        Ci = JpR @ Sig @ JpR.transpose(0, 2, 1) + (s_px**2)[:, None, None] * np.eye(2)[None]
        W = np.linalg.inv(Ci)
        e = np.sqrt(np.einsum("ni,nij,nj->n", r, W, r))  # Mahalanobis residual per point
        hub = np.where(e <= 1.345, 1.0, 1.345 / np.maximum(e, 1e-12))
        W = W * hub[:, None, None]
        H = np.einsum("nki,nkl,nlj->ij", J, W, J)
        g = np.einsum("nki,nkl,nl->i", J, W, r)
        try:
            d = np.linalg.solve(H, g)
            cov = np.linalg.inv(H)
        except np.linalg.LinAlgError:
            return rvec, tvec, None, float("nan")
        rvec, tvec = rvec + d[:3, None], tvec + d[3:, None]
        if np.abs(d).max() < 1e-7:
            break
    proj, _ = cv2.projectPoints(obj, rvec, tvec, Km, None)
    rmse = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - img) ** 2, axis=1))))
    return rvec, tvec, cov, rmse


def triangulate(px_m: np.ndarray, px_n: np.ndarray, T_m_n: np.ndarray, K: Intrinsics) -> np.ndarray:
    """Eq. (4): 3-D points (N, 3) in camera m from pixels in key frames m and n and ``T_m_n``.

    Linear (DLT) triangulation by ``cv2.triangulatePoints``; points behind either camera are NaN.
    """
    if len(px_m) == 0:
        return np.zeros((0, 3))
    Km = K.K
    T_n_m = np.linalg.inv(T_m_n)
    P_m = Km @ np.hstack([np.eye(3), np.zeros((3, 1))])
    P_n = Km @ T_n_m[:3]
    X = cv2.triangulatePoints(P_m, P_n, px_m.T.astype(np.float64), px_n.T.astype(np.float64))
    X = (X[:3] / X[3]).T
    z_n = (T_n_m[:3, :3] @ X.T).T[:, 2] + T_n_m[2, 3]
    X[(X[:, 2] <= 0) | (z_n <= 0)] = np.nan
    return X


def fill_missing_depth(
    ref: FrameFeatures, cur: FrameFeatures, pnp: PnPResult, K: Intrinsics, min_parallax_deg: float = 1.0
) -> int:
    """Give the current frame's features without depth a triangulated depth (eq. 4) from their match
    in the reference frame, where the parallax is large enough; returns how many were filled."""
    if not pnp.ok:
        return 0
    need = np.flatnonzero(~np.isfinite(cur.points[:, 2]))
    if len(need) < 2:
        return 0
    sub = FrameFeatures(cur.pixels[need], cur.descriptors[need], cur.points[need])
    m = OrbFrontEndMatches.all_matches(ref, sub)  # only the features that need a depth are matched
    if len(m) == 0:
        return 0
    m[:, 1] = need[m[:, 1]]
    X_ref = triangulate(ref.pixels[m[:, 0]], cur.pixels[m[:, 1]], pnp.T_ref_cur, K)
    T_cur_ref = np.linalg.inv(pnp.T_ref_cur)
    X_cur = (T_cur_ref[:3, :3] @ X_ref.T).T + T_cur_ref[:3, 3]
    # parallax: angle between the two viewing rays of the point
    c_ref = np.zeros(3)
    c_cur = pnp.T_ref_cur[:3, 3]
    a = X_ref - c_ref
    b = X_ref - c_cur
    cosang = np.einsum("ij,ij->i", a, b) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1) + 1e-12)
    ok = np.isfinite(X_cur[:, 2]) & (np.degrees(np.arccos(np.clip(cosang, -1, 1))) >= min_parallax_deg)
    cur.points[m[ok, 1]] = X_cur[ok]
    return int(ok.sum())


class OrbFrontEndMatches:
    """Matching without a settings object (brute force, ratio 0.8), used by :func:`fill_missing_depth`."""

    _matcher = cv2.BFMatcher(cv2.NORM_HAMMING)

    @classmethod
    def all_matches(cls, ref: FrameFeatures, cur: FrameFeatures, ratio: float = 0.8) -> np.ndarray:
        if len(ref.descriptors) < 2 or len(cur.descriptors) < 2:
            return np.zeros((0, 2), int)
        knn = cls._matcher.knnMatch(cur.descriptors, ref.descriptors, k=2)
        pairs = [
            (m[0].trainIdx, m[0].queryIdx)
            for m in knn
            if len(m) == 2 and m[0].distance < ratio * m[1].distance
        ]
        return np.array(pairs, int).reshape(-1, 2)
