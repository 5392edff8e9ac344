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
    depth_sigma: np.ndarray | None = None
    """(N,) 1-sigma of each point along its viewing ray [m] (NaN without a point); None: the head-on
    stereo model ``depth_noise``·z² (see :meth:`OrbFrontEnd.extract`)."""

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
MIN_COS = 0.1
"""Incidence cosine below which stereo noise stops growing (the camera model's ``min_cos``: beyond ~84°
the matcher returns no depth rather than a worse one)."""
NORMAL_SAMPLES = 7
"""Depth samples per side of the patch around a key point whose plane gives its surface normal."""
NORMAL_SPAN = 0.02
"""The patch's side as a fraction of the image width (13 px at VGA, 26 px at HD720: the same part of the
scene at every resolution, sampled on the same 7 x 7 grid)."""


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

    def add_depth_sigmas(self, feats: FrameFeatures, depth: np.ndarray | None, K: Intrinsics) -> None:
        """Give the points of ``feats`` (a key frame's: they become PnP and loop references) their depth
        sigma along the ray from the camera model, with the incidence angle of the plane fitted around
        each key point (:func:`local_plane`): sigma_z = ``depth_noise``·z²/max(cos θ, ``MIN_COS``), as
        stereo noise grows at grazing incidence (the head-on model is 3x overconfident there, measured).
        With ``depth_fit``, where the samples scatter about the plane no more than that noise predicts
        (99 % of chi²), the point moves onto the plane along its ray with the plane's smaller standard
        error (the ML depth from the patch's independent pixels, about 4x less noise): noisy reference
        depth shrank the PnP translations (errors in variables: nearer-measured points weigh more),
        0.4 % scale at VGA. Elsewhere (edges, curved surfaces) the measured depth stays, with the larger
        of the model's and the residuals' scatter. Off (``incidence_noise`` false) or without depth:
        ``depth_sigma`` stays None, the head-on model."""
        if depth is None or not self.s.incidence_noise or len(feats.points) == 0:
            return
        u = np.clip(np.round(feats.pixels[:, 0]).astype(int), 0, depth.shape[1] - 1)
        v = np.clip(np.round(feats.pixels[:, 1]).astype(int), 0, depth.shape[0] - 1)
        ok = np.flatnonzero(np.isfinite(feats.points[:, 2]) & (depth[v, u] > 0))  # measured, not eq. 4's
        sig = np.full(len(feats.points), np.nan)
        if len(ok):
            P = feats.points[ok]
            pl = local_plane(depth, u[ok], v[ok], P, K)
            s_q = self.s.depth_noise / np.maximum(pl.cos, MIN_COS)  # one sample's noise in 1/z [1/m]
            planar = (pl.dof > 0) & np.isfinite(pl.z)
            planar &= pl.rms**2 <= s_q**2 * (1 + 2.33 * np.sqrt(2 / np.maximum(pl.dof, 1)))
            z = P[:, 2]
            sig[ok] = z**2 * np.maximum(s_q, np.where(pl.dof > 0, pl.rms, 0.0))
            if self.s.depth_fit and planar.any():
                i = ok[planar]
                feats.points[i] *= (pl.z[planar] / z[planar])[:, None]
                sig[i] = pl.z[planar] ** 2 * s_q[planar] * pl.se[planar]
        feats.depth_sigma = sig

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
        if ref.depth_sigma is not None:
            s_z = ref.depth_sigma[m[:, 0]]
            s_z = np.where(np.isfinite(s_z), s_z, self.s.depth_noise * z**2)
        else:
            s_z = self.s.depth_noise * z**2
        Sig = s_lat[:, None, None] ** 2 * (np.eye(3)[None] - ray[:, :, None] * ray[:, None, :])
        Sig += (s_z**2)[:, None, None] * ray[:, :, None] * ray[:, None, :]
        return s_cur, Sig


@dataclass
class LocalPlane:
    """The plane fitted to the depth image around each key point (:func:`local_plane`), per key point."""

    cos: np.ndarray
    """|cos| of the incidence angle (viewing ray vs the plane's normal); ``MIN_COS`` where undetermined."""
    z: np.ndarray
    """The plane's depth on the key point's ray [m] (NaN where undetermined)."""
    se: np.ndarray
    """Standard error of the plane's 1/z on the key point's ray per unit noise of one sample's 1/z."""
    rms: np.ndarray
    """RMS residual of the samples' 1/z about the plane [1/m]."""
    dof: np.ndarray
    """Samples minus the plane's 3 parameters (0 where undetermined)."""


def local_plane(depth: np.ndarray, u: np.ndarray, v: np.ndarray, P: np.ndarray, K: Intrinsics) -> LocalPlane:
    """The plane fitted to the depth image on a 7 x 7 grid around each key point (pixel ``u``, ``v``; ``P``
    its 3-D point). For a plane, 1/z is linear in the normalised image coordinates (x, y, 1) with
    coefficients proportional to the normal; stereo noise is disparity noise, constant in 1/z (the
    camera's sigma_z = c·z²/cos is c/cos in 1/z), and the pixels are exact: an ordinary least-squares fit
    of 1/z is the maximum-likelihood plane (a fit of the 3-D points would tilt towards the rays, along
    which their noise lies). Samples of another surface (depth more than 30 % off) are left out; fewer
    than 6 samples, or samples on one line, leave the plane undetermined."""
    n = len(u)
    H, W = depth.shape
    half = max(1.0, NORMAL_SPAN * K.width / 2)
    off = np.round(np.linspace(-half, half, NORMAL_SAMPLES)).astype(int)
    du, dv = (a.ravel() for a in np.meshgrid(off, off))
    U = np.clip(u[:, None] + du, 0, W - 1)
    Vv = np.clip(v[:, None] + dv, 0, H - 1)
    Z = depth[Vv, U].astype(np.float64)
    zc = P[:, 2:3]
    with np.errstate(invalid="ignore"):
        w = (np.abs(Z - zc) <= 0.3 * zc).astype(np.float64)  # NaN and 0 (no depth) fail it
    y = w / np.where(w > 0, Z, 1.0)
    x1 = (U - K.cx) / K.fx
    x2 = (Vv - K.cy) / K.fy
    wx1, wx2 = w * x1, w * x2
    A = np.empty((n, 3, 3))
    A[:, 0, 0], A[:, 0, 1], A[:, 0, 2] = (wx1 * x1).sum(1), (wx1 * x2).sum(1), wx1.sum(1)
    A[:, 1, 1], A[:, 1, 2], A[:, 2, 2] = (wx2 * x2).sum(1), wx2.sum(1), w.sum(1)
    A[:, 1, 0], A[:, 2, 0], A[:, 2, 1] = A[:, 0, 1], A[:, 0, 2], A[:, 1, 2]
    b = np.stack([(y * x1).sum(1), (y * x2).sum(1), y.sum(1)], axis=1)
    # too few samples, or samples (nearly) on one line: a plane is not determined. The spread of the
    # samples' image coordinates, det of their 2x2 covariance, against a full patch's (~0.16 s^4)
    cnt = np.maximum(A[:, 2, 2], 1.0)
    mx, my = A[:, 0, 2] / cnt, A[:, 1, 2] / cnt
    spread = (A[:, 0, 0] / cnt - mx**2) * (A[:, 1, 1] / cnt - my**2) - (A[:, 0, 1] / cnt - mx * my) ** 2
    few = (A[:, 2, 2] < 6) | ~(spread > 0.0025 * (half / K.fx) ** 4)
    A[few] = np.eye(3)
    coef = np.linalg.solve(A, b[..., None])[..., 0]
    # the simulated camera's noise is Gaussian in z, not in 1/z: 1/z of a noisy sample is biased by
    # sigma²/z³ (the plane comes out 0.5 % too near at 7 m, grazing, measured). Gauss-Newton on the depths
    # themselves (residuals linearised into 1/z, so the same normal equations) removes it.
    Zs = np.where(w > 0, Z, 1.0)
    for _ in range(2):
        q = coef[:, 0:1] * x1 + coef[:, 1:2] * x2 + coef[:, 2:3]
        z0 = 1.0 / np.where(q > 1e-9, q, 1e-9)
        lin = w * (z0 - Zs) / z0**2  # = 1/Z - 1/z0 to first order, without its bias
        g = np.stack([(lin * x1).sum(1), (lin * x2).sum(1), lin.sum(1)], axis=1)
        coef = coef + np.linalg.solve(A, g[..., None])[..., 0]
    ray = P / np.linalg.norm(P, axis=1, keepdims=True)
    cos = np.abs(np.einsum("nk,nk->n", coef, ray)) / np.maximum(np.linalg.norm(coef, axis=1), 1e-12)
    r_c = P / P[:, 2:3]  # (x, y, 1) of the key point
    q_c = np.einsum("nk,nk->n", coef, r_c)
    se = np.sqrt(np.einsum("nk,nk->n", r_c, np.linalg.solve(A, r_c[..., None])[..., 0]))
    q = coef[:, 0:1] * x1 + coef[:, 1:2] * x2 + coef[:, 2:3]
    z0 = 1.0 / np.where(q > 1e-9, q, 1e-9)
    res = w * (z0 - Zs) / z0**2
    dof = np.where(few, 0, A[:, 2, 2] - 3)
    rms = np.sqrt((res**2).sum(1) / np.maximum(dof, 1))
    with np.errstate(divide="ignore"):
        z = np.where(few | (q_c <= 0), np.nan, 1.0 / q_c)
    cos[few] = MIN_COS
    return LocalPlane(cos, z, se, rms, dof)


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
    parallax = np.arccos(np.clip(cosang, -1, 1))
    ok = np.isfinite(X_cur[:, 2]) & (np.degrees(parallax) >= min_parallax_deg)
    cur.points[m[ok, 1]] = X_cur[ok]
    if cur.depth_sigma is not None:
        # eq. 4's own uncertainty along the current ray: the reference ray's pixel sigma (1.2^octave)
        # at the point's distance from the reference camera, over the sine of the parallax
        s_px = 1.2 ** ref.octaves[m[ok, 0]].astype(float) if ref.octaves is not None else 1.0
        lateral = s_px * np.linalg.norm(a[ok], axis=1) / K.fx
        cur.depth_sigma[m[ok, 1]] = lateral / np.sin(parallax[ok])
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
