"""Ellipse <-> conic round trips, sampling, distances and OpenCV's fitEllipse convention."""

import cv2
import numpy as np
import pytest

from livetrack.estimator.conics import Ellipse


def random_ellipses(n=20, seed=1):
    rng = np.random.default_rng(seed)
    for _ in range(n):
        a = rng.uniform(2.0, 500.0)
        b = a * rng.uniform(0.1, 1.0)
        yield Ellipse(rng.uniform(-100, 2000, 2), np.array([a, b]), rng.uniform(-4.0, 4.0))


def same_ellipse(e1, e2, tol=1e-7):
    scale = max(e1.a, 1.0)
    assert np.allclose(e1.centre_px, e2.centre_px, atol=tol * scale)
    assert np.allclose(e1.semi_axes_px, e2.semi_axes_px, rtol=tol)
    if e1.b < e1.a * (1 - 1e-6):  # the angle of a circle is arbitrary
        diff = (e1.angle_rad - e2.angle_rad + np.pi / 2) % np.pi - np.pi / 2
        assert abs(diff) < 1e-6


def test_constructor_normalises_axes_and_angle():
    e = Ellipse(np.array([1.0, 2.0]), np.array([3.0, 5.0]), 0.25)  # b > a: swapped, angle + 90 degrees
    assert e.semi_axes_px.tolist() == [5.0, 3.0]
    assert e.angle_rad == pytest.approx(0.25 + np.pi / 2)
    assert 0.0 <= Ellipse(np.zeros(2), np.array([2.0, 1.0]), -3.5).angle_rad < np.pi
    with pytest.raises(ValueError):
        Ellipse(np.zeros(2), np.array([1.0, 0.0]), 0.0)
    with pytest.raises(ValueError):
        Ellipse(np.array([np.nan, 0.0]), np.array([1.0, 1.0]), 0.0)


@pytest.mark.parametrize("ellipse", list(random_ellipses()))
def test_conic_round_trip_and_points_on_conic(ellipse):
    Q = ellipse.to_conic()
    assert np.allclose(Q, Q.T)
    assert np.linalg.norm(Q) == pytest.approx(1.0)
    assert ellipse.algebraic_distance(ellipse.centre_px[None, :])[0] < 0  # negative inside
    same_ellipse(Ellipse.from_conic(Q), ellipse)
    same_ellipse(Ellipse.from_conic(-3.7 * Q), ellipse)  # any scale and sign
    t = np.linspace(0, 2 * np.pi, 50, endpoint=False)
    pts = ellipse.points(t)
    assert pts.shape == (50, 2)
    assert np.max(np.abs(ellipse.sampson_distance(pts))) < 1e-6 * ellipse.a
    hom = np.column_stack([pts, np.ones(50)])
    assert np.max(np.abs(np.einsum("ij,jk,ik->i", hom, Q, hom))) < 1e-9


@pytest.mark.parametrize("ellipse", list(random_ellipses(8, seed=2)))
def test_normals_are_outward_unit_and_orthogonal_to_the_curve(ellipse):
    t = np.linspace(0, 2 * np.pi, 36, endpoint=False)
    n = ellipse.normals(t)
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0)
    tangent = ellipse.points(t + 1e-6) - ellipse.points(t - 1e-6)
    assert np.max(np.abs(np.einsum("ij,ij->i", n, tangent / np.linalg.norm(tangent, axis=1)[:, None]))) < 1e-6
    outside = ellipse.points(t) + 0.01 * ellipse.b * n
    assert np.all(ellipse.algebraic_distance(outside) > 0)


def test_sampson_distance_is_the_geometric_distance_near_the_curve():
    e = Ellipse(np.array([50.0, 40.0]), np.array([30.0, 12.0]), 0.7)
    t = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    for d in (-0.5, 0.2, 1.0):
        pts = e.points(t) + d * e.normals(t)
        assert np.allclose(e.sampson_distance(pts), d, atol=0.1 * d * d + 1e-9)  # second-order error


def test_from_conic_rejects_non_ellipses():
    hyperbola = np.diag([1.0, -1.0, -1.0])
    with pytest.raises(ValueError):
        Ellipse.from_conic(hyperbola)
    with pytest.raises(ValueError):
        Ellipse.from_conic(np.diag([1.0, 1.0, 1.0]))  # imaginary ellipse
    with pytest.raises(ValueError):
        Ellipse.from_conic(np.diag([1.0, 0.0, -1.0]))  # parabola-like / not central


def test_half_extent_bounds_the_points():
    e = Ellipse(np.array([0.0, 0.0]), np.array([20.0, 5.0]), 0.4)
    pts = e.points(np.linspace(0, 2 * np.pi, 20000))
    assert np.allclose(np.abs(pts).max(axis=0), e.half_extent_px(), atol=1e-3)


def render_filled(ellipse, shape, ss=8):
    """Anti-aliased coverage of the ellipse, pixel centres on integers."""
    h, w = shape
    ys, xs = np.mgrid[0 : h * ss, 0 : w * ss]
    x = (xs + 0.5) / ss - 0.5
    y = (ys + 0.5) / ss - 0.5
    inside = ellipse.algebraic_distance(np.column_stack([x.ravel(), y.ravel()])) < 0
    return inside.reshape(h * ss, w * ss).reshape(h, ss, w, ss).mean(axis=(1, 3))


@pytest.mark.parametrize("angle_deg", [0.0, 30.0, 90.0, 120.0, 165.0])
def test_fitellipse_convention(angle_deg):
    """cv2.fitEllipse: centre in pixel-centre coordinates, FULL axes, width along angle (degrees, +x toward
    +y). Contour points are the centres of the boundary pixels inside the shape: half a pixel in."""
    truth = Ellipse(np.array([100.3, 80.7]), np.array([40.0, 20.0]), np.deg2rad(angle_deg))
    coverage = render_filled(truth, (160, 200))
    binary = (coverage > 0.5).astype(np.uint8)
    contours, _ = cv2.findContours(binary, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    fitted = Ellipse.from_cv(cv2.fitEllipse(contours[0]))
    assert np.allclose(fitted.centre_px, truth.centre_px, atol=0.08)
    assert np.allclose(fitted.semi_axes_px + 0.5, truth.semi_axes_px, atol=0.15)
    diff = (fitted.angle_rad - truth.angle_rad + np.pi / 2) % np.pi - np.pi / 2
    assert abs(np.rad2deg(diff)) < 0.5
    # The subpixel centroid agrees: pixel centres are on integers.
    m = cv2.moments(coverage.astype(np.float32))
    assert np.allclose([m["m10"] / m["m00"], m["m01"] / m["m00"]], truth.centre_px, atol=0.01)


def test_from_cv_with_height_as_the_major_axis():
    e = Ellipse.from_cv(((10.0, 20.0), (8.0, 30.0), 30.0))
    assert e.semi_axes_px.tolist() == [15.0, 4.0]
    assert np.rad2deg(e.angle_rad) == pytest.approx(120.0)
