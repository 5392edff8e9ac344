"""Target-based hand-eye solvers (calibration board on the flange or in the cell) beside the flange
method: AX=XB (Tsai, Park, Horaud, Andreff, Daniilidis) and AX=YB robot-world/hand-eye (Shah, Li).

OpenCV's ``cv2.calibrateHandEye`` / ``cv2.calibrateRobotWorldHandEye`` (OpenCV 4.x; the project pins
``opencv-contrib-python-headless<5``) are used when the installed OpenCV exposes them (imported lazily,
here only) and ``backend`` is "auto" or "opencv". Without them (no OpenCV, or the 5.0 wheels, which
ship the method constants but not the two functions) the numpy implementations below run instead;
``info["backend"]`` says which one ran. The numpy versions build the same equations as OpenCV (all
pose pairs i < j, motions ``A = inv(G_j) G_i``, ``B = C_j inv(C_i)``; Andreff's and Li's translations
from their joint linear solutions) and agree with OpenCV 4.14 to ~1e-12 on noise-free and noisy data
(tests/handeye/test_handeye_algorithms.py), except Tsai's translation on noisy data (same rotation;
OpenCV 4.14's translation step differs from the plain least squares of Tsai's eq. 15 that we solve, by
~0.2 mm at 1 mm noise). Tsai is refused with a DataError when the hand-eye rotation is 180° (its
parametrization is singular there; OpenCV returns NaN).

Inputs are robot flange poses ``T_base_flange`` (n, 4, 4) and board poses ``T_cam_target``
(n, 4, 4). Eye-in-hand returns ``T_flange_camera``; eye-on-base returns ``T_base_camera``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import invert, orthonormalize, skew

HAND_EYE_METHODS = ("tsai", "park", "horaud", "andreff", "daniilidis")
ROBOT_WORLD_METHODS = ("shah", "li")
_TSAI_180 = (
    "Tsai's method cannot solve this data: the hand-eye rotation is (nearly) 180°, where its modified "
    "Rodrigues parameters are singular"
)
_TSAI_FIX = "use method park, horaud, andreff or daniilidis (or shah/li)"


def _cv2():
    try:
        import cv2
    except ImportError:  # pragma: no cover - depends on the install
        return None
    return cv2


def _relative(T: np.ndarray) -> np.ndarray:
    """Consecutive-pair relative motions ``inv(T_i) T_j`` for all pairs i < j (n(n-1)/2, 4, 4)."""
    i, j = np.triu_indices(len(T), 1)
    return np.einsum("nij,njk->nik", np.linalg.inv(T[i]), T[j])


def _translation_ls(A: np.ndarray, B: np.ndarray, R: np.ndarray) -> np.ndarray:
    """t_X from (R_A - I) t_X = R_X t_B - t_A (stacked least squares)."""
    M = (A[:, :3, :3] - np.eye(3)).reshape(-1, 3)
    rhs = (np.einsum("ij,nj->ni", R, B[:, :3, 3]) - A[:, :3, 3]).reshape(-1)
    return np.linalg.lstsq(M, rhs, rcond=None)[0]


def _ax_xb_numpy(A: np.ndarray, B: np.ndarray, method: str) -> np.ndarray:
    """Solve A_k X = X B_k for relative motions A (gripper) and B (camera)."""
    RA, RB = A[:, :3, :3], B[:, :3, :3]
    if method == "andreff":
        return _andreff(A, B, RA, RB)
    if method == "daniilidis":
        return _daniilidis(A, B)
    rotation = {"tsai": _rotation_tsai, "park": _rotation_park, "horaud": _rotation_horaud}.get(method)
    if rotation is None:
        raise DataError(f"unknown AX=XB method '{method}'", f"use one of {', '.join(HAND_EYE_METHODS)}")
    R = rotation(RA, RB)
    X = np.eye(4)
    X[:3, :3] = R
    X[:3, 3] = _translation_ls(A, B, R)
    return X


def _rotation_tsai(RA: np.ndarray, RB: np.ndarray) -> np.ndarray:
    """Tsai & Lenz 1989: the rotation from modified Rodrigues parameters."""
    rva, rvb = Rotation.from_matrix(RA).as_rotvec(), Rotation.from_matrix(RB).as_rotvec()
    ta, tb = np.linalg.norm(rva, axis=1), np.linalg.norm(rvb, axis=1)
    Pa = 2 * np.sin(ta / 2)[:, None] * rva / np.maximum(ta, 1e-12)[:, None]
    Pb = 2 * np.sin(tb / 2)[:, None] * rvb / np.maximum(tb, 1e-12)[:, None]
    M = np.concatenate([skew(a + b) for a, b in zip(Pa, Pb, strict=True)])
    Pp, _, _, sv = np.linalg.lstsq(M, (Pb - Pa).reshape(-1), rcond=None)
    if sv[-1] < 1e-9 * sv[0]:
        raise DataError(_TSAI_180, _TSAI_FIX)
    P = 2 * Pp / np.sqrt(1 + Pp @ Pp)
    n2 = P @ P
    R = (1 - n2 / 2) * np.eye(3) + 0.5 * (np.outer(P, P) + np.sqrt(4 - n2) * skew(P))
    R = orthonormalize(R)
    return R


def _rotation_park(RA: np.ndarray, RB: np.ndarray) -> np.ndarray:
    """Park & Martin 1994: the rotation from the log map."""
    al = Rotation.from_matrix(RA).as_rotvec()
    be = Rotation.from_matrix(RB).as_rotvec()
    M = be.T @ al
    w, V = np.linalg.eigh(M.T @ M)
    R = V @ np.diag(1 / np.sqrt(np.maximum(w, 1e-18))) @ V.T @ M.T
    R = orthonormalize(R)
    return R


def _rotation_horaud(RA: np.ndarray, RB: np.ndarray) -> np.ndarray:
    """Horaud & Dornaika 1995: the rotation in quaternion closed form."""
    qa = Rotation.from_matrix(RA).as_quat()[:, [3, 0, 1, 2]]
    qb = Rotation.from_matrix(RB).as_quat()[:, [3, 0, 1, 2]]
    S = np.zeros((4, 4))
    for a, b in zip(qa, qb, strict=True):
        if a[0] * b[0] < 0:
            b = -b
        La = np.array(
            [
                [a[0], -a[1], -a[2], -a[3]],
                [a[1], a[0], -a[3], a[2]],
                [a[2], a[3], a[0], -a[1]],
                [a[3], -a[2], a[1], a[0]],
            ]
        )
        Rb = np.array(
            [
                [b[0], -b[1], -b[2], -b[3]],
                [b[1], b[0], b[3], -b[2]],
                [b[2], -b[3], b[0], b[1]],
                [b[3], b[2], -b[1], b[0]],
            ]
        )
        D = La - Rb
        S += D.T @ D
    w, V = np.linalg.eigh(S)
    q = V[:, 0]
    R = Rotation.from_quat(q[[1, 2, 3, 0]]).as_matrix()
    return R


def _andreff(A: np.ndarray, B: np.ndarray, RA: np.ndarray, RB: np.ndarray) -> np.ndarray:
    """Andreff et al. 2001: linear in vec(R) and t."""
    n = len(A)
    K = np.zeros((12 * n, 12))
    rhs = np.zeros(12 * n)
    for k in range(n):
        K[12 * k : 12 * k + 9, :9] = np.eye(9) - np.kron(RA[k], RB[k])
        K[12 * k + 9 : 12 * k + 12, :9] = np.kron(np.eye(3), B[k, :3, 3])
        K[12 * k + 9 : 12 * k + 12, 9:] = np.eye(3) - RA[k]
        rhs[12 * k + 9 : 12 * k + 12] = A[k, :3, 3]
    x = np.linalg.lstsq(K, rhs, rcond=None)[0]
    Rr = x[:9].reshape(3, 3)
    Rr = np.sign(np.linalg.det(Rr)) * Rr / abs(np.linalg.det(Rr)) ** (1 / 3)
    X = np.eye(4)
    X[:3, :3], X[:3, 3] = orthonormalize(Rr), x[9:]  # t from the joint solution (eq. 10), as OpenCV
    return X


def _daniilidis(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Daniilidis 1999: dual quaternions + SVD."""

    def dq(T):
        q = Rotation.from_matrix(T[:, :3, :3]).as_quat()[:, [3, 0, 1, 2]]
        t = np.c_[np.zeros(len(T)), T[:, :3, 3]]
        return q, 0.5 * _qmul(t, q)

    qa, qa_d = dq(A)
    qb, qb_d = dq(B)
    flip = np.sum(qa * qb, axis=1) < 0  # pick the sign pair with equal scalar parts
    qb[flip], qb_d[flip] = -qb[flip], -qb_d[flip]
    rows = []
    for a, ad, b, bd in zip(qa, qa_d, qb, qb_d, strict=True):
        top = np.c_[(a - b)[1:, None], skew(a[1:] + b[1:]), np.zeros((3, 4))]
        bot = np.c_[(ad - bd)[1:, None], skew(ad[1:] + bd[1:]), (a - b)[1:, None], skew(a[1:] + b[1:])]
        rows.append(np.vstack([top, bot]))
    T = np.vstack(rows)
    _, _, Vt = np.linalg.svd(T)
    v7, v8 = Vt[6], Vt[7]
    u1, v1, u2, v2 = v7[:4], v7[4:], v8[:4], v8[4:]
    a_, b_, c_ = u1 @ v1, u1 @ v2 + u2 @ v1, u2 @ v2
    roots = np.roots([a_, b_, c_]) if abs(a_) > 1e-12 else np.array([-c_ / b_])
    best = None
    for s in np.real(roots):
        val = s * s * (u1 @ u1) + 2 * s * (u1 @ u2) + u2 @ u2
        if val > 0 and (best is None or val > best[0]):
            best = (val, s)
    val, s = best
    lam2 = np.sqrt(1 / val)
    lam1 = s * lam2
    q = lam1 * v7 + lam2 * v8
    qr, qd = q[:4], q[4:]
    R = Rotation.from_quat(qr[[1, 2, 3, 0]]).as_matrix()
    t = 2 * _qmul(qd[None], _qconj(qr)[None])[0, 1:]
    X = np.eye(4)
    X[:3, :3], X[:3, 3] = R, t
    return X


def _qmul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = p.T
    w2, x2, y2, z2 = q.T
    return np.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ],
        axis=-1,
    )


def _qconj(q: np.ndarray) -> np.ndarray:
    return q * np.array([1, -1, -1, -1])


def _ax_yb_numpy(A: np.ndarray, B: np.ndarray, method: str) -> tuple[np.ndarray, np.ndarray]:
    """Solve A_i X = Y B_i for X, Y (absolute poses)."""
    RA, RB, tA, tB = A[:, :3, :3], B[:, :3, :3], A[:, :3, 3], B[:, :3, 3]
    n = len(A)
    I3 = np.eye(3)
    if method == "shah":  # Shah 2013: Kronecker product, rotation first, translations after
        K = np.concatenate([np.c_[np.kron(RA[k], RB[k]), -np.eye(9)] for k in range(n)])
        _, _, Vt = np.linalg.svd(K)
        v = Vt[-1]
        Rx, Ry = v[:9].reshape(3, 3), v[9:].reshape(3, 3)
        s = np.sign(np.linalg.det(Rx)) / abs(np.linalg.det(Rx)) ** (1 / 3)
        Rx, Ry = orthonormalize(s * Rx), orthonormalize(s * Ry)
    elif method == "li":  # Li et al. 2010: rotations and translations in one linear system
        K = np.zeros((12 * n, 24))
        rhs = np.zeros(12 * n)
        for k in range(n):
            K[12 * k : 12 * k + 9, :9] = np.kron(RA[k], I3)
            K[12 * k : 12 * k + 9, 9:18] = -np.kron(I3, RB[k].T)
            K[12 * k + 9 : 12 * k + 12, 9:18] = -np.kron(I3, tB[k])
            K[12 * k + 9 : 12 * k + 12, 18:21] = RA[k]
            K[12 * k + 9 : 12 * k + 12, 21:24] = -I3
            rhs[12 * k + 9 : 12 * k + 12] = -tA[k]
        x = np.linalg.lstsq(K, rhs, rcond=None)[0]
        X, Y = np.eye(4), np.eye(4)  # rotations projected to SO(3), translations from the joint solution
        X[:3, :3], X[:3, 3] = orthonormalize(x[:9].reshape(3, 3)), x[18:21]
        Y[:3, :3], Y[:3, 3] = orthonormalize(x[9:18].reshape(3, 3)), x[21:24]
        return X, Y
    else:
        raise DataError(f"unknown AX=YB method '{method}'", f"use one of {', '.join(ROBOT_WORLD_METHODS)}")
    return _ax_yb_translation(A, B, Rx, Ry)


def _ax_yb_translation(A: np.ndarray, B: np.ndarray, Rx: np.ndarray, Ry: np.ndarray):
    """Translations of A_i X = Y B_i for fixed rotations: R_A,i t_X - t_Y = R_Y t_B,i - t_A,i (LS)."""
    n, I3 = len(A), np.eye(3)
    M = np.concatenate([np.c_[A[k, :3, :3], -I3] for k in range(n)])
    rhs = np.concatenate([Ry @ B[k, :3, 3] - A[k, :3, 3] for k in range(n)])
    t = np.linalg.lstsq(M, rhs, rcond=None)[0]
    X, Y = np.eye(4), np.eye(4)
    X[:3, :3], X[:3, 3] = Rx, t[:3]
    Y[:3, :3], Y[:3, 3] = Ry, t[3:]
    return X, Y


def _as_poses(T: np.ndarray, what: str) -> np.ndarray:
    T = np.asarray(T, float).reshape(-1, 4, 4)
    if not np.all(np.isfinite(T)):
        raise DataError(f"{what} contain NaN or infinite values", "drop the failed samples")
    return T


def _matched_poses(T_base_flange, T_cam_target) -> tuple[np.ndarray, np.ndarray]:
    """Flange and board poses as (N, 4, 4) stacks, at least 3 matched pairs."""
    G = _as_poses(T_base_flange, "flange poses")
    C = _as_poses(T_cam_target, "board poses")
    if len(G) != len(C) or len(G) < 3:
        raise DataError(
            f"{len(G)} flange poses and {len(C)} board poses; need >= 3 matched pairs", "collect more poses"
        )
    return G, C


def solve_hand_eye(
    T_base_flange: np.ndarray,
    T_cam_target: np.ndarray,
    config: str = "eye-in-hand",
    method: str = "tsai",
    backend: str = "auto",
    resolve_translation: bool = False,
) -> tuple[np.ndarray, dict]:
    """AX=XB hand-eye from flange and board poses. Returns (X, info): eye-in-hand X =
    ``T_flange_camera``, eye-on-base X = ``T_base_camera``; ``info`` holds the fixed-side transform
    (``T_base_target`` or ``T_flange_target``) and the backend used ("opencv" or "numpy").
    ``resolve_translation`` (not in OpenCV) re-solves t_X by least squares, (R_A - I) t_X = R_X t_B - t_A,
    with the final rotation: it changes Andreff's and Daniilidis' translations (simultaneous methods),
    which otherwise come from their joint solutions; see docs/methods/hand-eye.md for the gain."""
    method = method.lower()
    if method not in HAND_EYE_METHODS:
        raise DataError(f"unknown AX=XB method '{method}'", f"use one of {', '.join(HAND_EYE_METHODS)}")
    G, C = _matched_poses(T_base_flange, T_cam_target)
    if config == "eye-on-base":
        G = np.linalg.inv(G)  # base2gripper plays gripper2base; the result is cam2base
    cv2 = _cv2() if backend in ("auto", "opencv") else None
    if cv2 is not None and hasattr(cv2, "calibrateHandEye"):
        flag = getattr(cv2, f"CALIB_HAND_EYE_{method.upper()}")
        R, t = cv2.calibrateHandEye(G[:, :3, :3], G[:, :3, 3], C[:, :3, :3], C[:, :3, 3], method=flag)
        X = np.eye(4)
        X[:3, :3], X[:3, 3] = R, np.ravel(t)
        used = "opencv"
        if not np.all(np.isfinite(X)):
            if method == "tsai":
                raise DataError(_TSAI_180, _TSAI_FIX)
            raise DataError(
                f"OpenCV's {method} solver returned NaN on these poses", "check the pose diversity"
            )
    elif backend == "opencv":
        raise DataError("this OpenCV build has no cv2.calibrateHandEye", "use backend='numpy' or OpenCV 4.x")
    else:
        # all pairs i < j, OpenCV's order: gripper motion A = inv(G_j) G_i, camera motion
        # B = C_j inv(C_i); A X = X B
        i, j = np.triu_indices(len(G), 1)
        A = np.einsum("nij,njk->nik", np.linalg.inv(G[j]), G[i])
        B = np.einsum("nij,njk->nik", C[j], np.linalg.inv(C[i]))
        X = _ax_xb_numpy(A, B, method)
        used = "numpy"
    if resolve_translation:
        i, j = np.triu_indices(len(G), 1)
        A = np.einsum("nij,njk->nik", np.linalg.inv(G[j]), G[i])
        B = np.einsum("nij,njk->nik", C[j], np.linalg.inv(C[i]))
        X = X.copy()
        X[:3, 3] = _translation_ls(A, B, X[:3, :3])
    fixed = np.einsum("nij,jk,nkl->nil", G, X, C)  # G X C = constant (target in base / in flange)
    T_fixed = _mean_pose(fixed)
    res = np.linalg.norm(fixed[:, :3, 3] - T_fixed[:3, 3], axis=1)
    key = "T_flange_target" if config == "eye-on-base" else "T_base_target"
    return X, {key: T_fixed, "backend": used, "residuals": res}


def solve_robot_world(
    T_base_flange: np.ndarray,
    T_cam_target: np.ndarray,
    config: str = "eye-in-hand",
    method: str = "shah",
    backend: str = "auto",
    resolve_translation: bool = False,
) -> tuple[np.ndarray, dict]:
    """AX=YB robot-world/hand-eye (Shah, Li). Eye-in-hand: X = ``T_flange_camera`` and
    ``T_base_target``; eye-on-base: X = ``T_base_camera`` and ``T_flange_target``.
    ``resolve_translation`` (not in OpenCV) re-solves both translations by least squares with the final
    rotations (Li's otherwise come from the joint linear solution, whose rotation block is not yet a
    rotation; Shah already does this)."""
    method = method.lower()
    if method not in ROBOT_WORLD_METHODS:
        raise DataError(f"unknown AX=YB method '{method}'", f"use one of {', '.join(ROBOT_WORLD_METHODS)}")
    G, C = _matched_poses(T_base_flange, T_cam_target)
    # OpenCV form: cTw_i · wTb = cTg · gTb_i
    if config == "eye-on-base":
        A, B = np.linalg.inv(C), np.linalg.inv(G)  # c=target, w=camera, g=flange
    else:
        A, B = C, np.linalg.inv(G)  # c=camera, w=target, g=flange
    cv2 = _cv2() if backend in ("auto", "opencv") else None
    if cv2 is not None and hasattr(cv2, "calibrateRobotWorldHandEye"):
        flag = getattr(cv2, f"CALIB_ROBOT_WORLD_HAND_EYE_{method.upper()}")
        Rwb, twb, Rcg, tcg = cv2.calibrateRobotWorldHandEye(
            A[:, :3, :3], A[:, :3, 3], B[:, :3, :3], B[:, :3, 3], method=flag
        )
        wTb, cTg = np.eye(4), np.eye(4)
        wTb[:3, :3], wTb[:3, 3], cTg[:3, :3], cTg[:3, 3] = Rwb, np.ravel(twb), Rcg, np.ravel(tcg)
        used = "opencv"
    elif backend == "opencv":
        raise DataError(
            "this OpenCV build has no cv2.calibrateRobotWorldHandEye", "use backend='numpy' or OpenCV 4.x"
        )
    else:
        wTb, cTg = _ax_yb_numpy(A, B, method)
        used = "numpy"
    if resolve_translation:
        wTb, cTg = _ax_yb_translation(A, B, wTb[:3, :3], cTg[:3, :3])
    if config == "eye-on-base":
        X, other, key = invert(wTb), invert(cTg), "T_flange_target"
    else:
        X, other, key = invert(cTg), invert(wTb), "T_base_target"
    pred = np.einsum("nij,jk->nik", A, wTb)
    meas = np.einsum("ij,njk->nik", cTg, B)
    res = np.linalg.norm(pred[:, :3, 3] - meas[:, :3, 3], axis=1)
    return X, {key: other, "backend": used, "residuals": res}


def _mean_pose(T: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = Rotation.from_matrix(T[:, :3, :3]).mean().as_matrix()
    out[:3, 3] = T[:, :3, 3].mean(0)
    return out
