"""The whole-target model's compiled kernel (``target_model_kernel.white_kernel``) against its numpy reference, and
the analytic derivatives of the white and of both stages' residuals against finite differences (paper-lab's pose 3 at
x32, a 42 px target, and a pose tilted 40 deg nearer, both through the lens's distortion)."""

import math

import numpy as np
import pytest

from livetrack.estimator import target_model, target_model_kernel
from livetrack.geometry import Pose, rotation_from_rotvec
from tests.sweep_frames import paper_lab_frames

SATURATION = 4095 * 0.99


@pytest.fixture(scope="module")
def scene():
    scenario, (frame,) = paper_lab_frames(3, [32])
    return scenario, frame


def _poses(truth: Pose) -> list[Pose]:
    """The true pose and one tilted 40 deg about the image's x axis, 30 % nearer, a few mm off."""
    tilted = Pose(rotation_from_rotvec(np.array([math.radians(40.0), 0.0, 0.0])) @ truth.R,
                  0.7 * truth.t + np.array([0.003, -0.002, 0.0]))
    return [truth, tilted]


def test_the_kernel_agrees_with_the_numpy_reference(scene):
    """White and its six derivatives within 1e-9 (shares of a pixel; derivatives per rad and per m)."""
    scenario, frame = scene
    spec = scenario.targets[0]
    for pose in _poses(frame.truth[3]):
        window = target_model._Window(scenario.camera, pose, spec, frame.image, SATURATION)
        assert window.ok
        inverse = np.linalg.inv(pose.plane_to_normalized_homography())
        circles = target_model._circles(spec)
        args = (window.un, window.vn, window.around, inverse, pose.R, circles)
        white_np, d_np = target_model_kernel.white_numpy(*args, True)
        white_k, d_k = target_model_kernel.white_kernel(*args, True)
        plain_k, _ = target_model_kernel.white_kernel(*args, False)
        assert 0.05 < white_np.mean() < 0.95 and np.abs(d_np).max() > 10.0  # a target in the window, moving
        assert np.abs(white_k - white_np).max() < 1e-9 and np.abs(plain_k - white_np).max() < 1e-9
        assert np.abs(d_k - d_np).max() < 1e-9 * max(1.0, np.abs(d_np).max())


def test_the_whites_derivatives_match_finite_differences(scene):
    """Each derivative image against a central difference of the white (rotation 1e-6 rad, translation 1 um): the
    same pattern (correlation > 0.999, measured >= 0.9998) and the difference's norm within 3 % of theirs (measured
    0.03-2 %: the change of a pixel's size with the pose is left out of the analytic form)."""
    scenario, frame = scene
    spec = scenario.targets[0]
    circles = target_model._circles(spec)
    for pose in _poses(frame.truth[3]):
        window = target_model._Window(scenario.camera, pose, spec, frame.image, SATURATION)
        args = (window.un, window.vn, window.around)

        def white(p: Pose, args: tuple = args) -> np.ndarray:
            inverse = np.linalg.inv(p.plane_to_normalized_homography())
            return target_model_kernel.white_numpy(*args, inverse, p.R, circles, False)[0]

        inverse = np.linalg.inv(pose.plane_to_normalized_homography())
        _, d_white = target_model_kernel.white_numpy(*args, inverse, pose.R, circles, True)
        for k in range(6):
            step = 1e-6
            move = np.zeros(3)
            move[k % 3] = step
            if k < 3:
                plus = Pose(rotation_from_rotvec(move) @ pose.R, pose.t)
                minus = Pose(rotation_from_rotvec(-move) @ pose.R, pose.t)
            else:
                plus, minus = Pose(pose.R, pose.t + move), Pose(pose.R, pose.t - move)
            numeric = (white(plus) - white(minus)) / (2.0 * step)
            assert np.corrcoef(numeric.ravel(), d_white[k].ravel())[0, 1] > 0.999
            assert np.linalg.norm(d_white[k] - numeric) < 0.03 * np.linalg.norm(numeric)


def test_both_stages_jacobians_match_finite_differences(scene):
    """The fit's analytic Jacobians (stage 1: Kaufman's, projected on the linear levels' complement; stage 2: the
    censored model, also with the ground's share of white free) against forward differences of their residuals, column
    by column (cosine > 0.99)."""
    scenario, frame = scene
    spec, pose = scenario.targets[0], frame.truth[3]
    window = target_model._Window(scenario.camera, pose, spec, frame.image, SATURATION)
    interior = target_model._interior(window, pose, spec, 0.8)
    assert interior is not None
    stage1 = target_model._HaloOnInterior(window, spec, pose, interior)
    stage2 = target_model._WholeTarget(window, spec, pose, 0.8)
    p1 = np.concatenate([[1e-3, -2e-3, 5e-4], pose.t * 1.002, [math.log(6.0)]])
    p2 = np.concatenate([p1, [3400.0, 10.0, -5.0, math.log(66000.0), math.log(2000.0)]])
    steps1 = np.concatenate([np.full(3, 1e-6), np.full(3, 1e-6), [1e-5]])
    steps2 = np.concatenate([steps1, [1e-2, 1e-2, 1e-2, 1e-5, 1e-5]])
    ground = target_model._WithGroundShare(window, spec, pose, 0.8)  # stage 2 with the ground's share
    for model, p, steps in ((stage1, p1, steps1), (stage2, p2, steps2),
                            (ground, np.append(p2, 0.6), np.append(steps2, 1e-4))):
        analytic = model.jacobian(p)
        base = model.residuals(p)
        for k, step in enumerate(steps):
            moved = p.copy()
            moved[k] += step
            numeric = (model.residuals(moved) - base) / step
            cosine = numeric @ analytic[:, k] / (np.linalg.norm(numeric) * np.linalg.norm(analytic[:, k]))
            assert cosine > 0.99, (k, cosine)
