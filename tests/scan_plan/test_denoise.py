"""Bilateral filter (paper 000, eqs. 9-10), PCA normals and voxel down-sampling against known surfaces."""

from __future__ import annotations

import numpy as np
import pytest
from weldcell.plugins.scan_plan.denoise import (
    bilateral_filter,
    knn_table,
    largest_eigvec,
    mean_spacing,
    noise_level,
    pca_normals,
    radius_pairs,
    smallest_eigvec,
    sym3_eigvals,
    voxel_downsample,
)
from weldcell.sdk.errors import DataError

RNG = np.random.default_rng(0)
H, SIGMA, R = 0.001, 0.0003, 0.004  # 1 mm grid, 0.3 mm noise, 4 mm filter radius


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def gaussian_smoothing(P: np.ndarray, radius: float, sigma: float) -> np.ndarray:
    """The plain alternative: every point replaced by the Gaussian-weighted mean of its neighbours."""
    rows, cols, d = radius_pairs(P, radius)
    w = np.exp(-(d**2) / (2 * sigma**2))
    den = np.bincount(rows, weights=w, minlength=len(P))
    return (
        np.stack([np.bincount(rows, weights=w * P[cols, k], minlength=len(P)) for k in range(3)], 1)
        / den[:, None]
    )


def grid(n: int) -> tuple[np.ndarray, np.ndarray]:
    g = np.arange(n) * H
    return np.meshgrid(g, g)


def fillet_joint():
    """A 90-degree inside corner (floor z = 0, wall x = 0) with 0.3 mm noise along the normals."""
    A, B = grid(30)
    floor = np.c_[A.ravel(), B.ravel(), np.zeros(A.size)]
    wall = np.c_[np.zeros(A.size), B.ravel(), A.ravel() + H]
    P0 = np.r_[floor, wall]
    N0 = np.r_[np.tile([0, 0, 1.0], (len(floor), 1)), np.tile([1.0, 0, 0], (len(wall), 1))]
    return P0, P0 + N0 * RNG.normal(0, SIGMA, (len(P0), 1))


def dist_to_fillet(P: np.ndarray) -> np.ndarray:
    x, z = P[:, 0], P[:, 2]
    return np.minimum(np.hypot(np.minimum(x, 0), z), np.hypot(np.minimum(z, 0), x))


def test_bilateral_reduces_noise_on_a_plane():
    A, B = grid(40)
    P = np.c_[A.ravel(), B.ravel(), RNG.normal(0, SIGMA, A.size)]
    Q, N = bilateral_filter(P, R)
    inner = (P[:, 0] > R) & (P[:, 0] < 0.039 - R) & (P[:, 1] > R) & (P[:, 1] < 0.039 - R)
    assert rms(Q[inner, 2]) < rms(P[inner, 2]) / 2.5
    assert np.allclose(Q[:, :2], P[:, :2], atol=2e-4)  # moved along the normal only
    assert np.all(np.abs(N[inner, 2]) > 0.99)


def test_bilateral_reduces_noise_on_a_sphere():
    radius, n = 0.02, 30000
    v = RNG.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    P = v * (radius + RNG.normal(0, SIGMA, (n, 1)))
    Q, _ = bilateral_filter(P, R)
    err = lambda X: rms(np.linalg.norm(X, axis=1) - radius)  # noqa: E731
    assert err(Q) < err(P) / 2.0
    shrink = radius - np.mean(np.linalg.norm(Q, axis=1))
    assert abs(shrink) < 2e-4  # under 1 % of the radius
    assert abs(shrink) < radius - np.mean(np.linalg.norm(gaussian_smoothing(P, R, R / 2), axis=1))


def test_bilateral_preserves_a_sharp_edge_better_than_gaussian_smoothing():
    P0, P = fillet_joint()
    near_edge = (P0[:, 0] < R) & (P0[:, 2] < R + H)
    flat = ((P0[:, 0] > 2 * R) | (P0[:, 2] > 2 * R + H)) & (P0[:, 1] > R) & (P0[:, 1] < 0.029 - R)
    Q, _ = bilateral_filter(P, R, iterations=2)
    G = gaussian_smoothing(P, R, R / 2)
    edge_bil, edge_gauss = rms(dist_to_fillet(Q[near_edge])), rms(dist_to_fillet(G[near_edge]))
    assert edge_bil < 0.8 * rms(dist_to_fillet(P[near_edge]))  # the edge gets cleaner, not rounder
    assert edge_bil < 0.65 * edge_gauss  # Gaussian smoothing rounds the corner off
    assert rms(dist_to_fillet(Q[flat])) < rms(dist_to_fillet(P[flat])) / 3.0


def test_given_normals_and_sigmas_are_used():
    A, B = grid(20)
    P = np.c_[A.ravel(), B.ravel(), RNG.normal(0, SIGMA, A.size)]
    N = np.tile([0.0, 0.0, 1.0], (len(P), 1))
    Q, Nout = bilateral_filter(P, R, sigma_c=0.002, sigma_s=0.001, normals=N)
    assert np.array_equal(Nout, N) and np.array_equal(Q[:, :2], P[:, :2])
    assert rms(Q[:, 2]) < rms(P[:, 2])


def test_pca_normals_and_noise_level():
    A, B = grid(30)
    P = np.c_[A.ravel(), B.ravel(), 0.5 * A.ravel() + RNG.normal(0, 1e-4, A.size)]
    n_true = np.array([-0.5, 0.0, 1.0]) / np.linalg.norm([-0.5, 0.0, 1.0])
    for kw in (dict(k=15), dict(radius=0.003)):
        N = pca_normals(P, viewpoint=[0, 0, 1.0], **kw)
        assert np.all(N @ n_true > 0.99)  # oriented to the viewpoint above the plane
    assert noise_level(P, 0.003) == pytest.approx(1e-4 * n_true[2], rel=0.3)


def test_mean_spacing_and_voxel_downsample_keep_extent():
    A, B = grid(100)
    P = np.c_[A.ravel(), B.ravel(), np.zeros(A.size)]
    assert mean_spacing(P) == pytest.approx(H)
    D = voxel_downsample(P, factor=4.0)
    # the grid is tilted (denoise._GRID_AXES): a plane crosses ~1.4x the cells of an aligned grid
    assert len(P) / 16 < len(D) < 1.6 * len(P) / 16
    assert np.all(np.abs(np.ptp(D, axis=0) - np.ptp(P, axis=0)) <= 4 * H)
    assert np.all(D.min(0) >= P.min(0) - 1e-12) and np.all(D.max(0) <= P.max(0) + 1e-12)
    D2, N2 = voxel_downsample(P, voxel_size=0.01, normals=np.tile([0, 0, 1.0], (len(P), 1)))
    assert 100 < len(D2) < 180 and np.allclose(N2, [0, 0, 1])
    assert len(voxel_downsample(P, voxel_size=0.01)) == len(D2)  # one fixed grid: the same cells again


def test_voxel_centroids_of_a_noisy_plate_stay_on_it():
    """A plate at z = 10.2 mm with 0.5 mm of noise (a D415 at grazing views), down-sampled at 1.5 mm like
    the merged Table I scans: on a grid aligned with the plate the centroids form layers whose mean is
    0.25 mm off the plate (the noise straddles a grid plane at one phase everywhere); the tilted grid
    keeps them on it."""
    rng = np.random.default_rng(1)
    n = 400_000
    P = np.c_[rng.uniform(0, 0.06, n), rng.uniform(0, 0.06, n), 0.0102 + rng.normal(0, 5e-4, n)]
    D = voxel_downsample(P, voxel_size=0.0015)
    assert abs(D[:, 2].mean() - 0.0102) < 2e-5
    keys = np.floor(P / 0.0015).astype(np.int64)  # what an axis-aligned grid does
    _, inv = np.unique(keys, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    aligned = np.bincount(inv, weights=P[:, 2]) / np.bincount(inv)
    assert abs(aligned.mean() - 0.0102) > 2e-4


@pytest.mark.parametrize(
    "call",
    [
        lambda: bilateral_filter(np.empty((0, 3)), 0.01),
        lambda: bilateral_filter(np.array([[0, 0, 0], [np.nan, 0, 0], [1, 1, 1.0]]), 0.01),
        lambda: bilateral_filter(np.ones((10, 2)), 0.01),
        lambda: bilateral_filter(RNG.random((10, 3)), -1.0),
        lambda: bilateral_filter(RNG.random((10, 3)), 0.1, normals=np.ones((9, 3))),
        lambda: bilateral_filter(RNG.random((10, 3)), 0.1, iterations=0),
        lambda: voxel_downsample(RNG.random((10, 3)), voxel_size=0.0),
        lambda: voxel_downsample(np.empty((0, 3))),
        lambda: mean_spacing(np.zeros((1, 3))),
        lambda: pca_normals(np.full((5, 3), np.inf)),
        lambda: noise_level(RNG.random((10, 3)) * 100, 0.001),
    ],
)
def test_bad_inputs_raise_data_error(call):
    with pytest.raises(DataError) as err:
        call()
    assert err.value.fix


# ------------------------------------------------------------------- closed-form eigen, shared table


def test_closed_form_3x3_eigen_solver_matches_eigh():
    rng = np.random.default_rng(1)
    Q = rng.normal(size=(5000, 20, 3)) * np.array([1e-3, 5e-4, 1e-5])  # flat, elongated neighbourhoods
    Q = Q @ np.linalg.qr(rng.normal(size=(5000, 3, 3)))[0].transpose(0, 2, 1)
    D = Q - Q.mean(1, keepdims=True)
    C = D.transpose(0, 2, 1) @ D
    C[:3] = np.eye(3) * 1e-6  # degenerate: any unit vector is an eigenvector
    w, V = np.linalg.eigh(C)
    assert np.allclose(sym3_eigvals(C), w, rtol=0, atol=1e-9 * np.abs(w).max())
    for v, ref in ((smallest_eigvec(C), V[:, :, 0]), (largest_eigvec(C), V[:, :, 2])):
        assert np.allclose(np.linalg.norm(v, axis=1), 1.0)
        assert np.all(np.abs(np.einsum("ij,ij->i", v[3:], ref[3:])) > 1 - 1e-9)
    n0 = smallest_eigvec(C)
    resid = np.einsum("nij,nj->ni", C, n0) - sym3_eigvals(C)[:, :1] * n0
    assert np.abs(resid).max() < 1e-12


def test_bilateral_with_a_shared_table_equals_the_radius_search():
    P0, P = fillet_joint()
    table = knn_table(P, 80, radius=R)  # wide enough: every point within R is in the table
    assert (table.dist[:, 1:] <= R).sum(1).max() < 80
    a, na = bilateral_filter(P, R, sigma_s=2 * SIGMA)
    b, nb = bilateral_filter(P, R, sigma_s=2 * SIGMA, neighbours=table)
    assert np.allclose(a, b, atol=1e-12)
    assert np.all(np.abs(np.einsum("ij,ij->i", na, nb)) > 1 - 1e-9)
    with pytest.raises(DataError, match="reaches"):
        bilateral_filter(P, R, neighbours=knn_table(P, 80, radius=R / 2))
    with pytest.raises(DataError, match="another cloud"):
        bilateral_filter(P[::-1].copy(), R, neighbours=table)


def test_neighbour_table_follows_moved_points_and_sampled_spacing_is_close():
    _, P = fillet_joint()
    table = knn_table(P, 16, radius=0.003)
    assert np.all(table.idx[:, 0] == np.arange(len(P))) and np.all(table.dist[:, 0] == 0)
    moved = P + RNG.normal(0, 1e-5, P.shape)
    t2 = table.moved_to(moved)
    fin = np.isfinite(table.dist)
    assert np.allclose(t2.dist[fin], np.linalg.norm(moved[table.idx] - moved[:, None], axis=2)[fin])
    assert t2.matches(moved) and t2.matches(moved.copy())  # the same points, whichever array holds them
    moved[0] += 1e-4  # changed in place after the table was built: the table kept its own copy
    assert not t2.matches(moved) and not t2.matches(moved[1:])
    exact = mean_spacing(P)
    assert abs(mean_spacing(P, sample=500) - exact) < 0.05 * exact
