"""The configuration's camera, node, detector, input and output sections."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from stereopose.checks import DAY_S, FPS_MAX, FPS_MIN
from stereopose.config.fields import Section, _schema, number


@_schema("cameras[]")
@dataclass(frozen=True)
class CameraSource(Section):
    """One camera of a run: its calibration name and where its frames come from."""

    name: str = ""
    source: str = ""  # a video file, a folder of images, or an rtsp:// / http:// URL
    # a recorded file played forward then backward for ever, time stamps increasing (serve)
    loop: bool = False
    # optional low-resolution substream (URL or file) used for detection; `source` is used for
    # clips; empty: `source` for both
    detect: str = ""


@_schema("nodes[]")
@dataclass(frozen=True)
class NodeConfig(Section):
    """One detection node (`stereopose detect-node CONFIG --node NAME`): its cameras."""

    name: str = ""
    cameras: tuple[str, ...] = ()


@_schema("detector")
@dataclass(frozen=True)
class DetectorConfig(Section):
    # "auto": the fastest on this machine within the docs' accuracy (OpenVINO bf16 on a CPU
    # with bfloat16 instructions, else ONNX Runtime fp32; detection.choose), said at start
    backend: Literal["auto", "onnx", "openvino", "ultralytics"] = "auto"
    model: str | None = None  # a local .onnx or .pt file; default: yolo11n-pose from the cache
    # model input, long side
    imgsz: int = number(640, multiple_of=32, ge=32, le=8192)
    conf: float = number(0.25, ge=0.0, le=1.0)  # person score threshold
    iou: float = number(0.7, ge=0.0, le=1.0)  # NMS overlap threshold
    # cpu, cuda, cuda:N, tensorrt, tensorrt:N or auto; openvino: cpu, gpu, gpu.N or auto
    device: str = "cpu"
    # inference threads (default: all cores)
    threads: int | None = number(None, integer=True, ge=1, le=1024)
    # "fp32", "int8" (the INT8-quantised model; onnx only), "bf16" (openvino on a
    # CPU with bfloat16 instructions) or "fp16" (onnx on device tensorrt)
    # "auto": with backend auto, bf16 where it is chosen, else fp32; with a backend named, fp32
    precision: Literal["auto", "fp32", "bf16", "int8", "fp16"] = "auto"
    # detect where the people are (their tracks, each camera's own people, motion, periodic
    # full scans), at the camera's own resolution (detection.regional); false: every camera's
    # whole frame at imgsz, every step
    regions: bool = True
    # each region's model input side (a multiple of 32): smaller regions are enlarged to it,
    # larger ones shrunk
    region_imgsz: int = number(320, multiple_of=32, ge=64, le=4096)
    # each camera's whole frame scanned this often (staggered across cameras), seconds: someone
    # who walked in unseen and stands still is found within this and one step
    full_scan_s: float = number(3.0, gt=0.0, le=3600.0)
    # grey levels of change that count as motion (lower: more sensitive)
    motion_threshold: int = number(25, integer=True, ge=1, le=255)
    # a region's people seen at least this many times as finely as in the whole frame at
    # imgsz (a person too large for a region at that detail is detected in the whole frame);
    # below 1: large people cost less, their joints a little less exact
    region_detail: float = number(1.0, gt=0.0, le=4.0)
    # each camera's light measured (day, night, black, blinded: detection.light); a camera at
    # night (dark or noisy) has its pictures denoised and its contrast normalised for
    # the detector; false: measured only. Day pictures go to the detector unchanged
    night: bool = True
    # between detections, a camera whose people's sure joints all moved less than
    # carry_motion of their height between its last two detections skips the detector at its
    # next step (the cameras take turns), its people carried as last detected
    # (detection.carry); never two steps in a row. false: every camera detected every step
    carry: bool = True
    carry_motion: float = number(0.05, gt=0.0, le=1.0)


@_schema("input")
@dataclass(frozen=True)
class InputConfig(Section):
    sync: Literal["index", "time"] = "index"  # recorded cameras aligned by frame index or time
    # time steps per second (default: the first camera's frame rate)
    fps: float | None = number(None, ge=FPS_MIN, le=FPS_MAX)
    # stop after this many time steps
    max_frames: int | None = number(None, integer=True, ge=1)
    # live cameras: how long one try to open a stream, or one read, may take, seconds
    open_timeout_s: float = number(5.0, gt=0.0, le=600.0)
    # live cameras: end the run (exit 2) if no camera delivers a frame within this (none: wait)
    first_frame_timeout_s: float | None = number(30.0, gt=0.0, le=DAY_S)
    # cap on detection steps per second (default: as fast as the detector allows)
    detect_fps: float | None = number(None, ge=FPS_MIN, le=FPS_MAX)
    # serve: a live camera with a detection substream keeps its full stream encoded, for the
    # clips' full-stream copies ("copy"; nothing decoded), or decodes it for the drawn clips
    full_streams: Literal["copy", "decode"] = "copy"
    # live cameras: each stream decoded in a process of its own ("process": a decoder that
    # crashes, hangs or grows is restarted alone), or on a thread of the service ("thread")
    decoders: Literal["thread", "process"] = "process"
    # serve: where the cameras' 2D people come from: "local" (serve opens the cameras and
    # detects), or "nodes" (`stereopose detect-node` processes publish them on the site's
    # broker, [mqtt]; serve groups them into time steps by capture time)
    detection: Literal["local", "nodes"] = "local"
    # nodes: the cameras' frames within this many seconds of a step's first are one step
    # (default: half the step period, of detect_fps or else of the cameras' fps)
    node_window_s: float | None = number(None, gt=0.0, le=10.0)
    # nodes: the longest a step waits for its missing cameras, seconds after its first arrived
    node_wait_s: float = number(0.5, gt=0.0, le=10.0)
    # nodes: a node whose clock is off the service's by more than this is refused, seconds
    node_clock_tolerance_s: float = number(0.25, gt=0.0, le=3600.0)
    # nodes: each camera's picture (for the console and clips) sent this often, per second
    node_picture_hz: float = number(1.0, ge=0.0, le=30.0)
    # nodes: the pictures' scale of the calibration's size
    node_picture_scale: float = number(0.25, gt=0.0, le=1.0)


@_schema("outputs")
@dataclass(frozen=True)
class OutputConfig(Section):
    """What a run writes into its output folder."""

    poses: bool = True  # poses3d.jsonl
    events: bool = True  # events.jsonl and events.sqlite (with a site)
    trc: bool = True  # trc/person_<id>.trc
    csv: bool = True  # joints.csv
    two_way: bool = False  # trc/ and joints.csv smoothed both ways over each track, at the end
    overlays: bool = True  # overlays/<camera>.mp4: 2D skeletons, ids, reprojected 3D joints
    # overlay video size relative to the camera's frames
    overlay_scale: float = number(0.5, gt=0.0, le=1.0)
    report: bool = True  # report.html
    webhook: str | None = None  # POST each zone event to this URL
