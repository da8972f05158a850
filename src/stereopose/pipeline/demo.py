"""The real demo: Pose2Sim's 4-camera recording, its Qualisys calibration and a demo site."""

from __future__ import annotations

import shutil
from importlib import resources
from pathlib import Path

from stereopose.io.pose2sim_data import pose2sim_demo_dir

CAMERAS = ("cam01", "cam02", "cam03", "cam04")
TICKET = "demo_ticket.toml"


def _toml_str(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


def write_demo_config(out_dir: str | Path) -> Path:
    """Fetch the demo files (once) and write ``<out_dir>/demo.toml``, ``demo_site.toml`` and
    the demo's operation ticket ``demo_ticket.toml``, which its recording follows."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    demo = pose2sim_demo_dir() / "Demo_MultiPerson"
    site = resources.files("stereopose") / "data" / "demo_site.toml"
    (out_dir / "demo_site.toml").write_text(site.read_text(encoding="utf-8"), encoding="utf-8")
    ticket = resources.files("stereopose") / "data" / TICKET
    (out_dir / TICKET).write_text(ticket.read_text(encoding="utf-8"), encoding="utf-8")
    lines = [
        "# The real demo: Pose2Sim's multi-person recording (4 cameras, 1088x1920, 60 fps) with",
        "# its Qualisys calibration, through YOLO11n-pose, 3D reconstruction, tracking and fences.",
        f"calibration = {_toml_str(str(demo / 'calibration' / 'Calib.qca.txt'))}",
        'site = "demo_site.toml"',
        'output = "."',
        "",
    ]
    for name in CAMERAS:
        video = demo / "videos" / f"{name}.mp4"
        lines += ["[[cameras]]", f'name = "{name}"', f"source = {_toml_str(str(video))}", ""]
    path = out_dir / "demo.toml"
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


def write_serve_demo_config(
    out_dir: str | Path,
    data_dir: str | Path | None = None,
    port: int = 8787,
    *,
    imgsz: int = 640,
    detect_fps: float | None = None,
) -> Path:
    """``<out_dir>/serve.toml`` and ``demo_site.toml``: the real demo's four videos as cameras
    looped for ever (forward then backward), the demo site, the service's data in `data_dir`
    (default ``<out_dir>/data``), its HTTP server on 127.0.0.1:`port`. The demo files are
    fetched once."""
    out_dir = Path(out_dir)
    write_demo_config(out_dir)  # the site beside it, and the demo files fetched
    demo = pose2sim_demo_dir() / "Demo_MultiPerson"
    data = Path(data_dir).resolve() if data_dir is not None else out_dir.resolve() / "data"
    # the calibration copied beside the configuration: the service's corrections of it
    # (calibration_auto) are written beside it, in this folder, never in the shared cache
    shutil.copyfile(demo / "calibration" / "Calib.qca.txt", out_dir / "Calib.qca.txt")
    lines = [
        "# The real demo served: Pose2Sim's multi-person recording (4 cameras, 1088x1920,",
        "# 60 fps), each video played forward then backward for ever, through `stereopose serve`.",
        'calibration = "Calib.qca.txt"',
        'site = "demo_site.toml"',
        f"output = {_toml_str(str(data))}",
        "",
        "[detector]",
        f"imgsz = {int(imgsz)}",
        "",
        "[serve]",
        'host = "127.0.0.1"',
        f"port = {int(port)}",
        f"tickets = [{_toml_str(TICKET)}]  # planned: started from the console",
        "",
    ]
    if detect_fps is not None:
        lines[-1:-1] = ["[input]", f"detect_fps = {float(detect_fps)!r}", ""]
    for name in CAMERAS:
        video = demo / "videos" / f"{name}.mp4"
        lines += [
            "[[cameras]]",
            f'name = "{name}"',
            f"source = {_toml_str(str(video))}",
            "loop = true",
            "",
        ]
    path = out_dir / "serve.toml"
    path.write_text("\n".join(lines), encoding="utf-8")
    return path
