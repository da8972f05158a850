"""The keeping-up benchmark's set-up, briefly: the real demo's 4 cameras served as live HTTP
streams by ffmpeg, each with a 272x480 detection substream, detected as `serve` does (regions,
carried steps), its full streams decoded or kept encoded. The benchmark behind the README's
`serve` figures once stopped on its first step (a substream frame checked against the full
stream's calibrated size); this runs its own code so that it cannot silently break again."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from stereopose.config import DetectorConfig
from stereopose.detection import make_detector
from stereopose.detection.models import demo_videos

pytestmark = pytest.mark.realdata

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


@pytest.fixture(scope="module")
def keeping_up():
    sys.path.insert(0, str(BENCHMARKS))
    try:
        import keeping_up
    finally:
        sys.path.remove(str(BENCHMARKS))
    return keeping_up


@pytest.mark.parametrize("packets", [False, True], ids=["decoded", "kept-encoded"])
def test_the_keeping_up_benchmark_runs_with_substreams(keeping_up, tmp_path, packets) -> None:
    videos = demo_videos()
    subs = [keeping_up.substream(v, tmp_path / f"{v.stem}_sub.mp4") for v in videos]
    det = make_detector(backend="auto", threads=2)
    run = keeping_up.measure(videos, subs, 6.0, det, packets, 1, DetectorConfig())
    assert run["steps"] >= 3, run
    assert run["people_frames"] > 0, run  # people found, in the full frames' pixels
    assert run["full_streams"] == ("packets" if packets else "decoded")
    assert all(c["frames"] > 0 for c in run["substream_readers"].values()), run


def test_the_keeping_up_benchmark_runs_with_decoders_in_processes(keeping_up, tmp_path) -> None:
    videos = demo_videos()
    subs = [keeping_up.substream(v, tmp_path / f"{v.stem}_sub.mp4") for v in videos]
    det = make_detector(backend="auto", threads=2)
    run = keeping_up.measure(videos, subs, 6.0, det, True, 1, DetectorConfig(), "process")
    assert run["steps"] >= 3 and run["people_frames"] > 0, run
    assert run["decoders"] == "process" and run["cpu_s_per_step"] > 0, run
    assert all(c["decoded"] > 0 for c in run["substream_readers"].values()), run
