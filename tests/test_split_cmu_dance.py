"""configs/split_cmu_dance.json, the split of the shipped model's training data (docs/training.md step 11).

CMU's clips keep the split of the CMU folder's split.json (so validation and test stay comparable with
every earlier model), and every cmu-dance clip goes to train.
"""

from __future__ import annotations

from pathlib import Path

from smplik.data.dataset import SPLIT_NAMES, find_sources, load_split

REPO = Path(__file__).resolve().parents[1]
SPLIT = REPO / "configs" / "split_cmu_dance.json"


def test_cmu_clips_keep_their_split(shared_data) -> None:
    cmu_split = load_split(shared_data.cmu("split.json"))
    combined = load_split(SPLIT)
    for name in ("validation", "test"):
        assert combined.subjects[name] == cmu_split.subjects[name], name
        assert combined.clips[name] == cmu_split.clips[name], name
    for clip in find_sources(shared_data.cmu(), "bvh"):
        assert combined.assign(clip) == cmu_split.assign(clip), clip.name


def test_every_dance_clip_goes_to_train(shared_data) -> None:
    combined = load_split(SPLIT)
    dance = find_sources(shared_data.file("data/cmu-dance/README.md").parent, "bvh")
    assert len(dance) >= 30
    assert {SPLIT_NAMES[combined.assign(clip)] for clip in dance} == {"train"}
    held_out = combined.subjects["validation"] | combined.subjects["test"]
    assert not held_out & {clip.subject for clip in dance}
