"""Synthetic calibration data: a board shown at many positions to a simulated rig, as corner
observations with noise, or as rendered photos (lens distortion, blur, noise, uneven light)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from stereopose.calibration.board import Board
from stereopose.geometry.camera import project, undistort_normalized
from stereopose.types import Camera, Rig


@dataclass(frozen=True)
class BoardScene:
    """Board poses (board -> world, (4, 4)) by position name; `floor` lies on the floor with
    its first corner at `origin` (world) and its rows along world x."""

    board: Board
    poses: dict[str, np.ndarray]
    floor: str
    origin: np.ndarray


def _frame(z_axis: np.ndarray, spin: float) -> np.ndarray:
    z = z_axis / np.linalg.norm(z_axis)
    a = np.cross(z, [0.0, 0.0, 1.0])
    if np.linalg.norm(a) < 1e-6:
        a = np.array([1.0, 0.0, 0.0])
    x = a / np.linalg.norm(a)
    y = np.cross(z, x)
    c, s = np.cos(spin), np.sin(spin)
    x, y = c * x + s * y, -s * x + c * y
    return np.stack([x, y, z], axis=1)  # columns: board axes in the world


def board_scene(
    rig: Rig,
    board: Board,
    positions: int,
    rng: np.random.Generator,
    room: tuple[float, float] = (12.0, 8.0),
) -> BoardScene:
    """`positions` board poses over the room: the first on the floor, the others held up
    (centre 0.6-1.8 m high) facing a random camera, tilted and turned."""
    poses = {}
    origin = np.array([room[0] / 2 - 0.5, room[1] / 2 - 0.3, 0.0])
    # on the floor, printed side up: rows along world x, columns along world -y, z down
    floor = np.eye(4)
    floor[:3, :3] = np.diag([1.0, -1.0, -1.0])
    floor[:3, 3] = origin
    poses["pos00"] = floor
    centres = np.array([c.center for c in rig])
    half = 0.5 * board.square_m * np.array([board.cols - 1, board.rows - 1, 0.0])
    for k in range(1, positions):
        at = np.append(
            rng.uniform([2.0, 1.5], [room[0] - 2.0, room[1] - 1.5]), rng.uniform(0.6, 1.8)
        )
        toward = centres[rng.integers(len(centres))] - at
        toward = toward / np.linalg.norm(toward) + rng.normal(0, 0.25, 3)
        R = _frame(-toward, rng.uniform(-np.pi, np.pi))  # printed side (-z) toward the camera
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, at - R @ half
        poses[f"pos{k:02d}"] = T
    return BoardScene(board, poses, "pos00", origin)


def _sees(
    cam: Camera, T: np.ndarray, board: Board, max_angle_deg: float = 75.0
) -> np.ndarray | None:
    """The corners in the camera's pixels, or None when it cannot see the board's front or
    any corner falls outside its image."""
    obj = board.object_points()
    X = obj @ T[:3, :3].T + T[:3, 3]
    normal = -T[:3, 2]  # the printed side faces -z
    view = cam.center - X.mean(0)
    cosang = view @ normal / np.linalg.norm(view)
    if cosang < np.cos(np.radians(max_angle_deg)):
        return None
    px = project(X, cam)
    w, h = cam.size
    if (
        not np.isfinite(px).all()
        or (px < 5).any()
        or (px[:, 0] > w - 5).any()
        or (px[:, 1] > h - 5).any()
    ):
        return None
    return px


def corner_observations(
    rig: Rig, scene: BoardScene, noise_px: float, rng: np.random.Generator
) -> dict[str, dict[str, np.ndarray]]:
    """corners[camera][position] with Gaussian noise, for every camera that sees the board."""
    out: dict[str, dict[str, np.ndarray]] = {c.name: {} for c in rig}
    for name, T in scene.poses.items():
        for cam in rig:
            px = _sees(cam, T, scene.board)
            if px is not None:
                out[cam.name][name] = px + rng.normal(0, noise_px, px.shape)
    return out


def board_texture(board: Board, px_per_square: int = 40) -> tuple[np.ndarray, float]:
    """The printed board with a white margin of one square, and its pixels per metre. The
    edge u = k (pixels k - 1 and k meet at u = k - 0.5 in pixel-centre terms) lies at board
    x = k / ppm - 2 squares: inner corner 0 is one square inside the checkered area, which
    starts one square inside the margin."""
    n_x, n_y = board.cols + 1, board.rows + 1  # squares
    img = np.full(((n_y + 2) * px_per_square, (n_x + 2) * px_per_square), 255, np.uint8)
    for j in range(n_y):
        for i in range(n_x):
            if (i + j) % 2 == 0:
                y0, x0 = (j + 1) * px_per_square, (i + 1) * px_per_square
                img[y0 : y0 + px_per_square, x0 : x0 + px_per_square] = 0
    return img, px_per_square / board.square_m


class Renderer:
    """Renders the board into a camera's distorted image (one ray per pixel, computed once)."""

    def __init__(self, cam: Camera, board: Board, px_per_square: int = 40) -> None:
        self.cam, self.board = cam, board
        w, h = int(cam.size[0]), int(cam.size[1])
        uv = np.stack(
            np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64)), -1
        )
        xy = undistort_normalized(uv, cam)  # (h, w, 2) ideal normalised
        self.rays = np.concatenate([xy, np.ones((h, w, 1))], -1) @ cam.R  # world directions
        self.texture, self.ppm = board_texture(board, px_per_square)
        self.square_px = px_per_square

    def render(
        self,
        T: np.ndarray,
        rng: np.random.Generator,
        blur: float = 0.8,
        noise: float = 3.0,
        light: float = 0.3,
    ) -> np.ndarray:
        """Gray image of the board at pose T (board -> world) over a mid-gray background."""
        R, t = T[:3, :3], T[:3, 3]
        c = self.cam.center
        # ray c + s d meets the board plane (board z = 0): (R^T (c + s d - t))_z = 0
        n = R[:, 2]
        denom = self.rays @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            s = ((t - c) @ n) / denom
            P = c + s[..., None] * self.rays - t
            b = P @ R  # board coordinates
        # texture pixel k covers [k - 0.5, k + 0.5]: square edges fall between pixels
        map_x = ((b[..., 0] + 2 * self.board.square_m) * self.ppm - 0.5).astype(np.float32)
        map_y = ((b[..., 1] + 2 * self.board.square_m) * self.ppm - 0.5).astype(np.float32)
        bad = ~(s > 0)
        map_x[bad] = -1
        img = cv2.remap(
            self.texture,
            map_x,
            map_y,
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=128,
        ).astype(np.float64)
        h, w = img.shape
        gx, gy = np.meshgrid(np.linspace(-1, 1, w), np.linspace(-1, 1, h))
        a, b2 = rng.uniform(-1, 1, 2)
        img = img * (1.0 - light * 0.5 * (1 + a * gx + b2 * gy) / 2.0)  # uneven light
        if blur > 0:
            img = cv2.GaussianBlur(img, (0, 0), blur)
        img = img + rng.normal(0, noise, img.shape)
        return np.clip(img, 0, 255).astype(np.uint8)


def close_pose(
    cam: Camera,
    board: Board,
    rng: np.random.Generator,
    depth_m: tuple[float, float] = (0.9, 2.2),
    spread: float = 0.45,
) -> np.ndarray:
    """Board -> world (4, 4) of a board held depth_m in front of the camera, its centre up to
    `spread` of the image's half-width off the axis, tilted up to about 35 degrees."""
    depth = rng.uniform(*depth_m)
    x, y = rng.uniform(-spread, spread, 2) * depth * np.array(cam.size) / cam.focal
    R = _frame(np.array([0.0, 0.0, 1.0]) + rng.normal(0, 0.35, 3), rng.uniform(-0.6, 0.6))
    half = 0.5 * board.square_m * np.array([board.cols - 1, board.rows - 1, 0.0])
    in_cam = np.eye(4)
    in_cam[:3, :3], in_cam[:3, 3] = R, np.array([x, y, depth]) - R @ half
    cam_to_world = np.eye(4)
    cam_to_world[:3, :3], cam_to_world[:3, 3] = cam.R.T, cam.center
    return cam_to_world @ in_cam


def close_views(
    cam: Camera, board: Board, count: int, noise_px: float, rng: np.random.Generator
) -> dict[str, np.ndarray]:
    """Corners of `count` board photos taken for the camera's intrinsics (see close_pose)."""
    out: dict[str, np.ndarray] = {}
    k = 0
    while len(out) < count and k < 50 * count:
        k += 1
        px = _sees(cam, close_pose(cam, board, rng), board)
        if px is not None:
            out[f"close{len(out):02d}"] = px + rng.normal(0, noise_px, px.shape)
    return out
