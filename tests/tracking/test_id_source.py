"""The tracker's ids from an IdSource: a new person waits, tentative, while the source has no
id for it, and gets the source's next one as soon as it has; a plain first id counts on."""

from __future__ import annotations

from pathlib import Path

import pytest

from stereopose.config import Config
from stereopose.tracking.ids import CountingIds
from stereopose.tracking.memory import make_memory


class Gated:
    """Ids from 500 on, none while `open` is False (a log that cannot reserve more)."""

    def __init__(self) -> None:
        self.open, self.next, self.refused = False, 500, 0

    def take(self) -> int | None:
        if not self.open:
            self.refused += 1
            return None
        self.next += 1
        return self.next - 1


def test_a_new_person_waits_for_an_id_the_source_does_not_have(shared_data_dir: Path) -> None:
    from stereopose.calibration.formats import load_calibration
    from stereopose.detection.openpose import read_pose_dir
    from stereopose.reconstruction import Reconstructor

    rig = load_calibration(shared_data_dir / "calib.toml")
    frames = list(read_pose_dir(shared_data_dir / "pose", rig.names))[:40]
    rec = Reconstructor(rig)
    source = Gated()
    memory = make_memory(rig, Config(), first_id=source)
    seen: list[set[int]] = []
    for n, (f, people2d) in enumerate(frames):
        source.open = n >= 20
        prior = memory.prior(f)
        seen.append(set(memory.update(f, rec.reconstruct(f, people2d, prior)).ids.tolist()))
    assert not set().union(*seen[:20]) and source.refused > 0  # nobody given an id meanwhile
    assert memory.ids_waited == source.refused
    given = set().union(*seen[20:])
    assert given and given == set(range(500, source.next))  # the source's ids, none skipped
    assert seen[20], "the people who waited are output as soon as an id is there"


def test_a_plain_first_id_counts_on_and_is_checked() -> None:
    ids = CountingIds(7)
    assert [ids.take() for _ in range(3)] == [7, 8, 9]
    with pytest.raises(ValueError, match="first_id"):
        CountingIds(0)
