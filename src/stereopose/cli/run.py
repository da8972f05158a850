"""`detect`, `models`, `run`, `init`, `report` and the real `demo`."""

from __future__ import annotations

import argparse
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

from rich.table import Table

from stereopose.cli.common import _px, out, rate_progress, run_summary
from stereopose.cli.sim import _demo_synthetic
from stereopose.errors import ConfigError, IncompleteOutputError, StereoposeError

if TYPE_CHECKING:
    from stereopose.types import Event


def _demo(args: argparse.Namespace) -> int:
    if args.synthetic:
        return _demo_synthetic(args)
    from stereopose.pipeline.demo import TICKET, write_demo_config

    config = write_demo_config(args.out)
    overwrite = args.overwrite or _previous_demo(Path(args.out), config)
    out.print(
        "[bold]Real demo[/]: Pose2Sim's multi-person recording, 4 cameras (1088x1920, 60 fps), "
        f"its Qualisys calibration, a demo site and an operation ticket -> {config}"
    )
    title = "Real demo: detection, 3D reconstruction, tracking, zone and ticket events"
    rc = _run_config(config, title, overwrite, Path(args.out) / TICKET)
    out.print(
        f"open {Path(args.out) / 'report.html'} in a browser (the ticket followed: "
        f"{Path(args.out) / 'ticket.html'}); overlay videos in {Path(args.out) / 'overlays'}",
        highlight=False,
        soft_wrap=True,
    )
    return rc


def _previous_demo(out_dir: Path, config: Path) -> bool:
    """Whether the run in `out_dir` was this demo (its copy of the configuration used is this
    demo.toml): the demo replaces its own results, never another run's."""
    try:
        used = (out_dir / "config.toml").read_text(encoding="utf-8")
        return used == Path(config).read_text(encoding="utf-8")
    except OSError:
        return False


def _detect(args: argparse.Namespace) -> int:
    from stereopose.config import DetectorConfig, InputConfig, check_options
    from stereopose.detection import choice_of, make_detector
    from stereopose.pipeline import detect_videos

    check_options(args, InputConfig, DetectorConfig)  # --fps, --max-frames, --imgsz, ...
    detector = make_detector(
        args.backend,
        args.model,
        args.imgsz,
        args.conf,
        args.iou,
        args.device,
        args.threads,
        args.precision,
    )
    out.print(f"detector: {choice_of(detector) or args.backend}", highlight=False)
    regions = None
    if args.regions:
        from stereopose.detection.call_costs import CallCosts
        from stereopose.detection.regional import RegionDetector, RegionSettings

        settings = RegionSettings(imgsz=args.region_imgsz, full_scan_s=args.full_scan_s)
        regions = RegionDetector(detector, settings, CallCosts.of(detector))
    progress = rate_progress("detecting")
    with progress:
        task = progress.add_task("detecting", total=None, fps=0.0)
        summary = detect_videos(
            args.videos,
            args.out,
            detector,
            names=args.names,
            sync=args.sync,
            fps=args.fps,
            max_frames=args.max_frames,
            overwrite=args.overwrite,
            model=args.model,
            regions=regions,
            on_step=lambda done, total, fps: progress.update(
                task, completed=done, total=total, fps=fps
            ),
        )
    table = Table(title=f"2D keypoints written to {args.out}")
    for col in ("camera", "frames", "with people", "people/frame", "dropped", "reconnects"):
        table.add_column(col, justify="left" if col == "camera" else "right")
    for name in summary.cameras:
        n = summary.frames[name]
        st = summary.sources[name]
        table.add_row(
            name,
            str(n),
            str(summary.frames_with_people[name]),
            f"{summary.people[name] / n:.2f}" if n else "-",
            str(st.dropped),
            str(st.reconnects),
        )
    out.print(table)
    steps_s = summary.seconds_decode + summary.seconds_detect + summary.seconds_write
    out.print(
        f"{summary.steps} time steps, {summary.images} images with the {summary.backend} backend: "
        f"{summary.ms_per_image:.1f} ms per image detecting, "
        f"{1000 * summary.seconds_decode / max(summary.steps, 1):.1f} ms per step decoding, "
        f"{summary.steps / steps_s if steps_s else 0:.1f} time steps/s overall",
        highlight=False,
    )
    if summary.regions:
        from stereopose.detection.regional import describe

        out.print(describe(summary.regions), highlight=False)
    if summary.failed_outputs:
        folders = {
            str(Path(args.out) / f"{n}_json"): why for n, why in summary.failed_outputs.items()
        }
        raise IncompleteOutputError(folders, summary=summary)
    if summary.interrupted:
        out.print("interrupted: the files above are complete up to the last time step")
        return 130
    return 0


def _models(args: argparse.Namespace) -> int:
    from stereopose.detection import models

    if args.action == "fetch":
        out.print(str(models.fetch_default_weights()), highlight=False, soft_wrap=True)
    elif args.action == "export" and args.int8:
        out.print(str(_export_int8(models, args)), highlight=False, soft_wrap=True)
    elif args.action == "export" and args.openvino_int8:
        _said_int8(_export_openvino_int8(models, args))
    elif args.action == "export":
        if args.weights is None and args.out is None and not args.force:
            target = models.models_dir() / f"{models.DEFAULT_MODEL}.onnx"
            path = target if target.is_file() else models.default_onnx()
        else:
            path = models.export_onnx(args.weights, args.out)
        out.print(str(path), highlight=False, soft_wrap=True)
        if args.weights is None and args.out is None:
            _default_openvino_int8(models, args.force)
    else:
        found = models.list_models()
        if not found:
            out.print(f"no models in {models.models_dir()}; run `stereopose models export`")
        for path in found:
            out.print(f"{path}  {path.stat().st_size / 1e6:.1f} MB", highlight=False)
    return 0


def _default_openvino_int8(models: ModuleType, force: bool) -> None:
    """OpenVINO's INT8 model of the default model, made once where OpenVINO and NNCF are
    installed (a runtime install says how to do without)."""
    import importlib.util

    target = models.openvino_int8_path()
    if target.is_file() and not force and _current_int8(target):
        _said_int8(target)
        return
    missing = [m for m in ("openvino", "nncf") if importlib.util.find_spec(m) is None]
    if missing:
        out.print(
            f"OpenVINO's INT8 model not made: {' and '.join(missing)} not installed "
            "(pip install 'stereopose[openvino,int8]'); detection runs the float model",
            highlight=False,
        )
        return
    if not models.int8_videos():
        out.print(
            "OpenVINO's INT8 model not made: the real recordings it is quantised on are not "
            "in the cache (`python -m stereopose.io.pose2sim_data` unpacks them); detection "
            "runs the float model",
            highlight=False,
        )
        return
    from stereopose.detection.int8_openvino import quantize_int8_openvino

    _said_int8(quantize_int8_openvino(out=target))


def _export_openvino_int8(models: ModuleType, args: argparse.Namespace) -> Path:
    """OpenVINO's INT8 model of the .onnx (or .pt) given, or of the default model."""
    if args.weights is None:
        src = models.default_onnx()
        target = args.out or models.openvino_int8_path()
    else:
        src = models.check_weights(Path(args.weights))
        if src.suffix == ".pt":
            src = models.export_onnx(src, models.models_dir() / f"{src.stem}.onnx")
        target = args.out or models.models_dir() / f"{src.stem}{models.INT8_SUFFIX}.xml"
    if Path(target).is_file() and not args.force and _current_int8(Path(target)):
        return Path(target)
    from stereopose.detection.int8_openvino import quantize_int8_openvino

    return quantize_int8_openvino(src, target)


def _current_int8(path: Path) -> bool:
    """Whether the INT8 model at `path` was made by today's recipe (else it is made again,
    and the user told why)."""
    from stereopose.detection.int8_openvino import current

    if current(path):
        return True
    out.print(f"{path}: made by an older recipe, made again", highlight=False, soft_wrap=True)
    return False


def _said_int8(path: Path) -> None:
    """The OpenVINO INT8 model's path and its check against fp32, on one line."""
    from stereopose.detection.int8_openvino import read_check

    found = read_check(path) or {}
    if found.get("accepted"):
        verdict = "within the bound: auto takes it where it is faster"
    elif "p95_px" in found:
        verdict = f"over the {found.get('p95_bound_px')} px bound: auto does not take it"
    else:
        verdict = "no check beside it: auto does not take it"
    out.print(
        f"{path} (joints {found.get('p95_px', '?')} px p95 from fp32's, {verdict})",
        highlight=False,
        soft_wrap=True,
    )


def _export_int8(models: ModuleType, args: argparse.Namespace) -> Path:
    """The INT8 model: of the .onnx given (or the cache's default), written to --out or beside
    it; an existing one is kept unless --force."""
    if args.weights is None:
        src = models.default_onnx()
        target = (
            args.out or models.models_dir() / f"{models.DEFAULT_MODEL}{models.INT8_SUFFIX}.onnx"
        )
    else:
        src = models.check_weights(Path(args.weights))
        if src.suffix == ".pt":
            src = models.export_onnx(src, models.models_dir() / f"{src.stem}.onnx")
        target = args.out or src.with_name(f"{src.stem}{models.INT8_SUFFIX}.onnx")
    if Path(target).is_file() and not args.force:
        return Path(target)
    return models.quantize_int8(src, target)


def _run_config(
    config_path: Path,
    title: str,
    overwrite: bool = False,
    ticket_path: Path | None = None,
    zone_states: Path | None = None,
) -> int:
    if not Path(config_path).exists():  # at once, before the pipeline is imported
        raise ConfigError(f"{config_path}: configuration file not found")
    from stereopose.io.sinks import describe
    from stereopose.pipeline.run import run
    from stereopose.tickets import load_ticket

    ticket = load_ticket(ticket_path) if ticket_path is not None else None

    progress = rate_progress("running")
    with progress:
        task = progress.add_task("running", total=None, fps=0.0)

        def show(events: list[Event]) -> None:
            for e in events:
                progress.console.print(describe(e), markup=False, highlight=False)

        incomplete: IncompleteOutputError | None = None
        try:
            summary = run(
                config_path,
                on_step=lambda done, total, fps: progress.update(
                    task, completed=done, total=total, fps=fps
                ),
                on_events=show,
                overwrite=overwrite,
                ticket=ticket,
                zone_states=zone_states,
            )
        except IncompleteOutputError as e:  # the run is done: its table first, then exit 3
            incomplete, summary = e, run_summary(e)
    d = summary.as_dict()
    table = Table(title=title, show_header=False)
    table.add_row("cameras", ", ".join(summary.cameras))
    table.add_row(
        "frames",
        f"{summary.steps} ({'live' if summary.live else 'recorded'}, "
        f"{summary.fps_input:g} frames/s)",
    )
    table.add_row("speed", f"{summary.fps:.1f} frames/s overall")
    table.add_row(
        "per stage, frames/s",
        ", ".join(f"{k} {v:.0f}" for k, v in summary.stage_fps().items() if v is not None),
    )
    table.add_row("compiled loops loaded", f"in {summary.load_s_3d:.2f} s (before the first frame)")
    table.add_row(
        "people", f"{len(summary.people)} tracked, {summary.people_per_frame:.2f} per frame"
    )
    events = ", ".join(f"{v} {k}" for k, v in sorted(summary.events.items()))
    table.add_row("zone events", events or "none")
    table.add_row(
        "reprojection error (median)",
        ", ".join(
            f"{k} {_px(v['reprojection_median_px'] or float('nan'))}"
            for k, v in d["per_camera"].items()
        ),
    )
    if summary.regions:
        from stereopose.detection.regional import describe as regions_line

        table.add_row("detection", regions_line(summary.regions).removeprefix("regions: "))
    out.print(table)
    if summary.people:
        people = Table(title="People tracked")
        for col in ("id", "first frame", "last frame", "time in view s", "path m"):
            people.add_column(col, justify="right")
        for p in summary.people:
            people.add_row(
                str(p["id"]),
                str(p["first_frame"]),
                str(p["last_frame"]),
                f"{p['duration_s']:.2f}",
                f"{p['path_m']:.2f}",
            )
        out.print(people)
    out.print(f"outputs in {summary.out_dir}:", highlight=False)
    for path in summary.outputs:
        out.print(f"  {path}", markup=False, highlight=False, soft_wrap=True)
    if incomplete is not None:
        incomplete.written = []  # listed above
        raise incomplete
    if summary.interrupted:
        out.print("interrupted: every output above is complete up to the last frame processed")
        return 130
    return 0


def _run(args: argparse.Namespace) -> int:
    return _run_config(
        args.config, f"run {args.config}", args.overwrite, args.ticket, args.zone_states
    )


def _init(args: argparse.Namespace) -> int:
    from importlib import resources

    path = Path(args.path or ("stereopose-serve.toml" if args.serve else "stereopose.toml"))
    if path.exists() and not args.force:
        raise StereoposeError(f"{path}: already exists (use --force to overwrite)")
    example = "example_serve.toml" if args.serve else "example_run.toml"
    text = (resources.files("stereopose") / "data" / example).read_text("utf-8")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
    except OSError as e:
        raise StereoposeError(f"{path}: cannot write: {e.strerror}") from None
    command = "serve" if args.serve else "run"
    out.print(
        f"wrote {path}: edit the calibration, cameras and outputs, then "
        f"`stereopose {command} {path}`",
        highlight=False,
        soft_wrap=True,
    )
    return 0


def _report(args: argparse.Namespace) -> int:
    from stereopose.viz.report import write_report

    out.print(f"wrote {write_report(args.run_dir)}", markup=False, highlight=False, soft_wrap=True)
    return 0
