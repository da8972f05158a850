"""Overlay drawing: reprojected 3D people in their colours, with their ids, over a frame."""

from __future__ import annotations

import cv2
import numpy as np

from stereopose.geometry.camera import project
from stereopose.sim import simulate
from stereopose.types import People3D
from stereopose.viz.overlay import OverlayVideo, colour, draw_overlay


def _people(scene, frame: int, ids) -> People3D:
    joints = scene.truth[frame][: len(ids)]
    P = len(ids)
    return People3D(
        frame,
        joints,
        np.ones((P, 17)),
        np.array(ids),
        np.zeros((P, 17)),
        np.full((P, 17), 2),
        np.zeros((P, len(scene.rig)), int),
    )


def test_reprojected_joints_drawn_in_the_person_colour():
    scene = simulate(num_cameras=4, num_people=2, num_frames=5, seed=3, difficulty="easy")
    cam = scene.rig[0]
    people = _people(scene, 2, [4, 7])
    w, h = (int(v) for v in cam.size)
    image = np.zeros((h, w, 3), np.uint8)
    out = draw_overlay(image, cam, scene.detections[2].get(cam.name), people, scale=0.5)
    assert out.shape == (h // 2, w // 2, 3) and image.max() == 0  # the input is untouched
    for p, pid in enumerate([4, 7]):
        px = project(people.joints[p], cam) * 0.5
        inside = np.isfinite(px).all(1) & (px[:, 0] > 0) & (px[:, 0] < w / 2 - 1)
        inside &= (px[:, 1] > 0) & (px[:, 1] < h / 2 - 1)
        # the case is built with both people in view: a person out of it would check nothing
        assert inside.sum() >= 5, f"id {pid}: {inside.sum()} joints in the image"
        hits = sum((out[round(y), round(x)] == colour(pid)).all() for x, y in px[inside])
        assert hits >= (inside.sum() + 1) // 2, pid


def test_overlay_video_written_and_readable(tmp_path):
    scene = simulate(num_cameras=2, num_people=1, num_frames=3, seed=1, difficulty="easy")
    cam = scene.rig[0]
    w, h = (int(v) for v in cam.size)
    video = OverlayVideo(tmp_path / "cam.mp4", cam, 25.0, scale=0.25)
    for f in range(3):
        video.write(np.full((h, w, 3), 40, np.uint8), None, _people(scene, f, [1]), f"frame {f}")
    path = video.close()
    cap = cv2.VideoCapture(str(path))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 3
    ok, frame = cap.read()
    assert ok and frame.shape == (round(h * 0.25), round(w * 0.25), 3)
