"""The camera model against OpenCV: projection with distortion and its inverse."""

import cv2
import numpy as np
import pytest

import evservo

CAMERAS = {
    "imx636": evservo.Camera.imx636(),
    "full": evservo.Camera(640, 480, 502.3, 505.1, 320.4, 240.7, dist=(-0.21, 0.08, 0.001, -0.0015, -0.012)),
}


@pytest.mark.parametrize("name", CAMERAS)
def test_projection_with_distortion_equals_opencv(name):
    cam = CAMERAS[name]
    rng = np.random.default_rng(3)
    pts = rng.uniform([-0.25, -0.15, 0.4], [0.25, 0.15, 1.2], size=(2000, 3))
    ours = cam.project(pts)
    ref, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), cam.k, np.array(cam.dist))
    assert np.abs(ours - ref[:, 0]).max() < 1e-6


@pytest.mark.parametrize("name", CAMERAS)
def test_rectification_inverts_distortion_like_opencv(name):
    cam = CAMERAS[name]
    rng = np.random.default_rng(4)
    raw = rng.uniform([100, 80], [cam.width - 100, cam.height - 80], size=(500, 2))
    ours = cam.rectify_pixels(raw)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    # OpenCV 4.x takes the stopping criteria in undistortPointsIter (5.x folded it into undistortPoints).
    ref = cv2.undistortPointsIter(raw[:, None, :], cam.k, np.array(cam.dist), None, cam.k, criteria)[:, 0]
    assert np.abs(ours - ref).max() < 1e-4
    # And back: distorting the rectified pixel returns the raw one.
    rays = np.column_stack([(ours - [cam.cx, cam.cy]) / [cam.fx, cam.fy], np.ones(len(ours))])
    assert np.abs(cam.project(rays) - raw).max() < 1e-6


def test_points_behind_the_camera_project_to_nan():
    uv = CAMERAS["imx636"].project(np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 0.0]]))
    assert np.isnan(uv).all()
