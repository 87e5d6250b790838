"""The embedded synthetic corpus: layout, text format, determinism, splits, physical plausibility
of the motions, left/right semantics, and that the text determines the motion."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from m2d2m.motion.representation.skeleton import T2M
from pipelines import synthetic as syn

CLIPS, SEED = 60, 7
FOOT_JOINTS = (7, 8, 10, 11)  # ankles and toes


@pytest.fixture(scope="module")
def corpus(tmp_path_factory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("synthetic")
    return out, syn.generate_corpus(out, clips=CLIPS, seed=SEED)


@pytest.fixture(scope="module")
def annotations(corpus) -> list[dict]:
    out, _ = corpus
    return [json.loads(line) for line in (out / "annotations.jsonl").read_text().splitlines()]


@pytest.fixture(scope="module")
def motions(corpus, annotations) -> dict[str, np.ndarray]:
    out, _ = corpus
    return {a["id"]: np.load(out / "joints" / f"{a['id']}.npy") for a in annotations}


def _text_lines(out: Path, clip_id: str) -> list[str]:
    return (out / "texts" / f"{clip_id}.txt").read_text(encoding="utf-8").splitlines()


def _inflections(lemma: str) -> set[str]:
    """Regular -s / -ing forms of a lemma, and the irregular ones this vocabulary uses."""
    stem = lemma[:-1] if lemma.endswith("e") else lemma
    return {
        lemma + "s",
        lemma + "es",
        lemma[:-1] + "ies",
        stem + "ing",
        lemma + lemma[-1] + "ing",
        {"foot": "feet", "do": "does"}.get(lemma, ""),
    }


def _heading(joints: np.ndarray) -> np.ndarray:
    """Per-frame body yaw (+ = turned left, counterclockwise from above) from the hips."""
    across = joints[:, 1] - joints[:, 2]  # towards the body's left
    return np.unwrap(np.arctan2(-across[:, 2], across[:, 0]))


def _body_frame(joints: np.ndarray, frame: int) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal unit vectors (left, forward) of the body at ``frame``."""
    left = joints[frame, 1] - joints[frame, 2]
    left[1] = 0.0
    left /= np.linalg.norm(left)
    return left, np.cross(left, [0.0, 1.0, 0.0])


# --------------------------------------------------------------------------- layout and text


def test_layout_and_joint_files(corpus, annotations, motions):
    out, summary = corpus
    assert len(annotations) == CLIPS == summary["clips"]
    assert [a["id"] for a in annotations] == [f"{i:06d}" for i in range(CLIPS)]
    for clip_id, joints in motions.items():
        assert re.fullmatch(r"\d{6}", clip_id)
        assert joints.dtype == np.float32 and joints.ndim == 3 and joints.shape[1:] == (22, 3)
        assert syn.MIN_FRAMES <= len(joints) <= syn.MAX_FRAMES
        assert np.isfinite(joints).all()
    meta = json.loads((out / "corpus.json").read_text())
    assert meta["seed"] == SEED and meta["clips"] == CLIPS and meta["version"]
    assert meta["families"] == list(syn.FAMILIES)


def test_annotations_describe_ordered_actions(annotations, motions):
    for a in annotations:
        assert 1 <= len(a["actions"]) <= 3 and a["frames"] == len(motions[a["id"]])
        ends = [0] + [x["end"] for x in a["actions"]]
        for action, previous_end in zip(a["actions"], ends):
            assert action["family"] in syn.FAMILIES
            assert previous_end <= action["start"] < action["end"] <= a["frames"]
        assert 0.85 <= a["body_scale"] <= 1.15 and len(a["captions"]) == 3


def test_caption_lines_follow_humanml3d(corpus, annotations):
    out, _ = corpus
    for a in annotations:
        lines = _text_lines(out, a["id"])
        assert len(lines) == 3
        captions = [line.split("#")[0] for line in lines]
        assert len(set(captions)) == 3 and captions == a["captions"]
        for line in lines:
            caption, tokens, start, end = line.split("#")
            assert (start, end) == ("0.0", "0.0") and caption == caption.lower()
            words = re.findall(r"[a-z]+", caption)
            pairs = [t.rsplit("/", 1) for t in tokens.split()]
            assert len(pairs) == len(words)  # one token per word, punctuation dropped
            for word, (token, tag) in zip(words, pairs):
                assert tag in syn.UPOS and tag != "PUNCT" and token.isalpha()
                if tag not in ("NOUN", "VERB") or word == "left":
                    assert token == word
                elif token != word:  # lemmatised: the word is an inflection of its token
                    assert word in _inflections(token), f"{word} → {token}"


def test_lemmas_and_tags_in_humanml3d_style(corpus, annotations):
    out, _ = corpus
    tokens = " ".join(line.split("#")[1] for a in annotations for line in _text_lines(out, a["id"]))
    for inflected in (
        "walks/VERB",
        "walking/VERB",
        "sits/VERB",
        "steps/NOUN",
        "hands/NOUN",
        "times/NOUN",
        "is/VERB",
        "his/DET",
        "feet/NOUN",
    ):
        assert inflected not in tokens
    rng = np.random.default_rng(0)
    plans = [
        [("walk", {"steps": 4, "speed": "slow"}), ("sit_down", {"speed": "normal"})],
        [("wave", {"side": "left", "count": 3}), ("turn", {"side": "left", "angle": 90})],
    ]
    lines = [syn.caption_line(c) for _ in range(20) for plan in plans for c in syn.make_captions(plan, rng)]
    joined = "\n".join(lines)
    assert "sit/VERB down/ADP" in joined and "left/ADJ hand/NOUN" in joined
    assert "turn/VERB left/ADV" in joined or "to/ADP the/DET left/NOUN" in joined
    for line in lines:
        caption, tags = line.split("#")[:2]
        if " is " in f" {caption} ":
            assert "is/AUX" in tags
        for pronoun in ("his", "her", "their"):
            if f" {pronoun} " in f" {caption} ":
                assert f"{pronoun}/PRON" in tags
        if "left" in caption.split():
            assert re.search(r"\bleft/(ADJ|ADV|NOUN)", tags)


def test_multi_verb_share_at_the_default_mix(corpus, annotations):
    out, summary = corpus
    assert summary["multi_verb_share"] >= 0.3
    assert summary["captions"] == 3 * CLIPS
    counted = sum(line.split("#")[1].count("/VERB") >= 2 for a in annotations for line in _text_lines(out, a["id"]))
    assert counted / (3 * CLIPS) == pytest.approx(summary["multi_verb_share"], abs=1e-3)


def test_postures_chain_plausibly(annotations):
    for a in annotations:
        families = [x["family"] for x in a["actions"]]
        for i, family in enumerate(families):
            if family == "stand_up":
                assert i == 0 or families[i - 1] == "sit_down"
            if i and families[i - 1] == "sit_down":
                assert family == "stand_up"
            if i:
                assert family != families[i - 1]


# --------------------------------------------------------------------------- determinism, splits


def test_same_seed_same_bytes_whatever_the_workers(corpus, tmp_path):
    out, _ = corpus
    syn.generate_corpus(tmp_path / "again", clips=10, seed=SEED, workers=2)
    syn.generate_corpus(tmp_path / "other", clips=10, seed=SEED + 1)
    for i in range(10):
        for rel in (f"joints/{i:06d}.npy", f"texts/{i:06d}.txt"):
            assert (out / rel).read_bytes() == (tmp_path / "again" / rel).read_bytes()
    differs = [
        (out / f"joints/{i:06d}.npy").read_bytes() != (tmp_path / "other" / f"joints/{i:06d}.npy").read_bytes()
        for i in range(10)
    ]
    assert all(differs)


def test_rewriting_a_smaller_corpus_removes_stale_clips(tmp_path):
    syn.generate_corpus(tmp_path, clips=5, seed=1, families=["clap"])
    syn.generate_corpus(tmp_path, clips=3, seed=1, families=["clap"])
    assert sorted(p.stem for p in (tmp_path / "joints").glob("*.npy")) == ["000000", "000001", "000002"]


def test_a_corpus_of_an_older_generator_is_never_taken_for_the_current_one(tmp_path):
    syn.generate_corpus(tmp_path, clips=2, seed=1, families=["clap"])
    assert syn.existing_corpus(tmp_path, 2, 1, ["clap"])
    record = json.loads((tmp_path / "corpus.json").read_text())
    assert record["texture"]["wrists"] == syn.TEXTURE.wrists
    (tmp_path / "corpus.json").write_text(json.dumps({**record, "version": "1.0"}))
    with pytest.raises(ValueError, match="other version"):
        syn.existing_corpus(tmp_path, 2, 1, ["clap"])


def test_splits_are_disjoint_and_cover_all_ids(corpus):
    out, summary = corpus
    splits = {name: (out / f"{name}.txt").read_text().split() for name in ("train", "val", "test")}
    ids = [f"{i:06d}" for i in range(CLIPS)]
    assert sorted(sum(splits.values(), [])) == ids
    assert {k: len(v) for k, v in splits.items()} == summary["splits"]
    large = [f"{i:06d}" for i in range(2000)]
    assigned = syn.assign_splits(large, seed=3)
    assert {k: len(v) for k, v in assigned.items()} == {"train": 1600, "val": 100, "test": 300}
    assert set().union(*map(set, assigned.values())) == set(large)
    assert assigned == syn.assign_splits(large, seed=3) != syn.assign_splits(large, seed=4)


def test_family_filter_and_invalid_names(tmp_path):
    summary = syn.generate_corpus(tmp_path, clips=8, seed=2, families=["wave", "clap"])
    assert set(summary["families"]) == {"wave", "clap"} and sum(summary["families"].values()) >= 8
    records = [json.loads(x) for x in (tmp_path / "annotations.jsonl").read_text().splitlines()]
    assert {a["family"] for r in records for a in r["actions"]} <= {"wave", "clap"}
    with pytest.raises(ValueError, match="valid: walk"):
        syn.generate_corpus(tmp_path, clips=2, families=["moonwalk"])


# --------------------------------------------------------------------------- physical plausibility


def test_bones_keep_their_length_and_sides_match(motions):
    for joints in motions.values():
        lengths = T2M.bone_lengths_of(joints.astype(np.float64))
        assert lengths.std(axis=0).max() < 1e-5
        mean = lengths.mean(axis=0)
        np.testing.assert_allclose(mean[list(T2M.left_joints)], mean[list(T2M.right_joints)], atol=1e-5)


def test_planted_feet_do_not_slide(motions):
    """A foot joint counts as planted where it stays within 1 cm of its floor height for four
    frames in a row (lift-off and touchdown take one or two frames, so they are excluded); a
    planted joint must not move more than 2 mm per frame horizontally (the generator pins it, so
    anything above float noise would be sliding)."""
    checked = 0
    for joints in motions.values():
        for joint in FOOT_JOINTS:
            height = joints[:, joint, 1]
            low = height < height.min() + 0.01
            planted = low[:-3] & low[1:-2] & low[2:-1] & low[3:]
            step = np.linalg.norm(np.diff(joints[:, joint, ::2], axis=0)[1:-1], axis=-1)
            checked += planted.sum()
            assert step[planted].max(initial=0.0) < 0.002
    assert checked > 0.3 * sum(len(j) for j in motions.values()) * len(FOOT_JOINTS)


def test_feet_stay_on_or_above_the_floor_and_the_head_above_the_pelvis(motions):
    for joints in motions.values():
        assert joints[..., 1].min() >= 0.0
        assert joints[:, FOOT_JOINTS, 1].min() < 0.03  # and they do touch it
        assert (joints[:, 15, 1] - joints[:, 0, 1]).min() > 0.25


def test_knees_never_bend_backwards(motions):
    for joints in motions.values():
        joints = joints.astype(np.float64)
        left = joints[:, 1] - joints[:, 2]
        for hip, knee, ankle in ((1, 4, 7), (2, 5, 8)):
            thigh, shin = joints[:, knee] - joints[:, hip], joints[:, ankle] - joints[:, knee]
            bend = np.einsum("ti,ti->t", np.cross(thigh, shin), left)
            bend /= np.linalg.norm(thigh, axis=-1) * np.linalg.norm(shin, axis=-1) * np.linalg.norm(left, axis=-1)
            assert bend.min() > 0.0  # sine of the flexion, signed so that forward is positive


def test_no_jumps_between_frames_or_actions(motions):
    for joints in motions.values():
        step = np.linalg.norm(np.diff(joints, axis=0), axis=-1)
        assert step[:, 0].max() < 0.3  # the root never moves faster than 6 m/s
        acceleration = np.linalg.norm(joints[2:] - 2 * joints[1:-1] + joints[:-2], axis=-1)
        assert acceleration.max() < 0.5  # m/frame², a kick's snap is the fastest thing here


def test_root_travel_matches_the_feet(motions, annotations):
    """The pelvis goes where the feet go: after each action the root is above the feet again,
    so its horizontal travel equals the feet's (stride × cadence is the speed)."""
    for a in annotations:
        joints = motions[a["id"]]
        for action in a["actions"]:
            start, end = action["start"], action["end"] - 1
            root = joints[end, 0, ::2] - joints[start, 0, ::2]
            feet = joints[end, [7, 8]].mean(0)[::2] - joints[start, [7, 8]].mean(0)[::2]
            tolerance = 0.45 if action["family"] in ("sit_down", "stand_up") else 0.08
            assert np.linalg.norm(root - feet) < tolerance


# --------------------------------------------------------------------------- text ↔ motion


def _single(family: str, count: int = 8, seed: int = 11):
    for i in range(count):
        clip = syn.make_clip(i, seed, (family,), max_actions=1)
        (_, params), (start, end) = clip.plan[0], clip.segments[0]
        yield params, clip.joints.astype(np.float64), start, end


def test_sides_and_directions_match_the_words():
    side_joint = {"left": 0, "right": 1}
    for params, j, start, end in _single("wave"):
        if params["side"] != "both":
            wrist, other = (20, 21) if params["side"] == "left" else (21, 20)
            assert j[:, wrist, 1].max() > j[:, 15, 1].min() - 0.15 > j[:, other, 1].max()
    for params, j, start, end in _single("kick"):
        kicking, standing = ((7, 8), (8, 7))[side_joint[params["side"]]]
        assert j[:, kicking, 1].max() > j[:, standing, 1].max() + 0.2
    for params, j, start, end in _single("hop"):
        lifted, stance = (8, 7) if params["side"] == "left" else (7, 8)  # hop on the left: right foot up
        assert j[start + 15, lifted, 1] > j[start + 15, stance, 1] + 0.15
    for params, j, start, end in _single("sidestep"):
        left, _ = _body_frame(j, start)
        moved = (j[end - 1, 0] - j[start, 0]) @ left
        assert moved > 0.3 if params["side"] == "left" else moved < -0.3
    for params, j, start, end in _single("turn"):
        turned = np.degrees(_heading(j)[end - 1] - _heading(j)[start])
        expected = params["angle"] * (1 if params["side"] == "left" else -1)
        assert abs(turned - expected) < 12
    for params, j, start, end in _single("walk_circle"):
        turned = np.degrees(_heading(j)[end - 1] - _heading(j)[start])
        assert abs(turned - (-360 if params["direction"] == "clockwise" else 360)) < 15
    for params, j, start, end in _single("walk_backwards"):
        _, forward = _body_frame(j, start)
        assert (j[end - 1, 0] - j[start, 0]) @ forward < -0.3
    for params, j, start, end in _single("punch"):
        _, forward = _body_frame(j, start)
        fist, other = (20, 21) if params["side"] == "left" else (21, 20)
        reach = (j[:, [fist, other]] - j[:, [0]]) @ forward
        assert reach[:, 0].max() > reach[:, 1].max() + 0.15


def test_arms_swing_opposite_to_the_legs():
    for family in ("walk", "run"):
        for params, j, start, end in _single(family, 4):
            forward = np.stack([_body_frame(j, f)[1] for f in range(start, end)])
            legs = np.einsum("ti,ti->t", j[start:end, 7] - j[start:end, 8], forward)
            arms = np.einsum("ti,ti->t", j[start:end, 20] - j[start:end, 21], forward)
            assert np.corrcoef(legs, arms)[0, 1] < -0.7


def test_speed_words_order_the_speeds():
    speeds = {}
    for family in ("walk", "jog", "run"):
        for params, j, start, end in _single(family, 10):
            travel = np.linalg.norm(j[end - 1, 0, ::2] - j[start, 0, ::2])
            speeds.setdefault((family, params["speed"]), []).append(travel / (end - start) * 20.0)
    mean = {k: np.mean(v) for k, v in speeds.items()}
    assert mean[("walk", "slow")] < mean[("walk", "normal")] < mean[("walk", "fast")]
    assert mean[("walk", "fast")] < mean[("jog", "normal")] < mean[("run", "fast")]


def _clip_features(joints: np.ndarray) -> np.ndarray:
    """Mean and spread of the pose in the body's own frame, the pose at the start and the end,
    root speed, turning and height: simple joint statistics, independent of the representation."""
    yaw = _heading(joints)
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    rel = joints - joints[:, :1] * np.array([1.0, 0.0, 1.0])
    x = c * rel[..., 0] - s * rel[..., 2]
    z = s * rel[..., 0] + c * rel[..., 2]
    local = np.stack([x, rel[..., 1], z], axis=-1)
    speed = np.linalg.norm(np.diff(joints[:, 0, ::2], axis=0), axis=-1)
    velocity = np.linalg.norm(np.diff(local, axis=0), axis=-1)
    third = len(joints) // 3
    rise = joints[-third:, 0, 1].mean() - joints[:third, 0, 1].mean()
    return np.concatenate(
        [
            local.mean(0).ravel(),
            local.std(0).ravel(),
            velocity.mean(0),
            [rise],
            [speed.mean(), speed.std(), np.abs(np.diff(yaw)).sum(), joints[:, 0, 1].min(), np.diff(yaw).sum()],
        ]
    )


def test_families_are_separable_from_the_motion(tmp_path):
    """Nearest centroid on simple joint statistics, trained on the train split of single-action
    clips and scored on the others: far above the 1/18 chance level."""
    summary = syn.generate_corpus(tmp_path, clips=270, seed=5, max_actions=1)
    records = [json.loads(x) for x in (tmp_path / "annotations.jsonl").read_text().splitlines()]
    labels = {r["id"]: r["actions"][0]["family"] for r in records}
    features = {i: _clip_features(np.load(tmp_path / "joints" / f"{i}.npy").astype(np.float64)) for i in labels}
    train = (tmp_path / "train.txt").read_text().split()
    held_out = (tmp_path / "val.txt").read_text().split() + (tmp_path / "test.txt").read_text().split()
    x = np.stack([features[i] for i in train])
    mean, std = x.mean(0), x.std(0) + 1e-6
    families = sorted({labels[i] for i in train})
    centroids = np.stack([((x - mean) / std)[[labels[i] == f for i in train]].mean(0) for f in families])
    correct = 0
    for i in held_out:
        distance = np.linalg.norm(centroids - (features[i] - mean) / std, axis=-1)
        correct += families[int(distance.argmin())] == labels[i]
    accuracy = correct / len(held_out)
    print(f"nearest-centroid family accuracy on {len(held_out)} held-out clips: {accuracy:.2f}")
    assert len(summary["families"]) == 18 and accuracy > 0.6


def test_band_noise_has_unit_acceleration_and_nothing_below_its_band():
    from pipelines.synthetic import FPS, band_noise

    x = band_noise(400, (3,), np.random.default_rng(0), low_hz=4.0)
    assert x.shape == (400, 3)
    assert np.sqrt(np.mean(np.diff(x, n=2, axis=0) ** 2)) == pytest.approx(1.0)
    power = np.abs(np.fft.rfft(np.diff(x, n=2, axis=0), axis=0)) ** 2
    freqs = np.fft.rfftfreq(398, 1.0 / FPS)
    below, inside = power[(freqs > 0.3) & (freqs < 1.5)].mean(), power[freqs > 5.0].mean()
    assert below < 0.01 * inside  # the motion's own band (under low_hz / 2) is left alone


def test_texture_adds_high_frequencies_only_where_asked_and_keeps_the_body_rigid():
    from pipelines.synthetic import Texture

    smooth = syn.make_clip(3, seed=5, texture=Texture()).joints
    textured = syn.make_clip(3, seed=5).joints
    assert syn.TEXTURE.pelvis > 0 and syn.TEXTURE.wrists > 0
    # same plan, body and captions (the texture has its own random stream), different jerk
    assert smooth.shape == textured.shape
    assert syn.make_clip(3, seed=5, texture=Texture()).captions == syn.make_clip(3, seed=5).captions
    difference = np.abs(textured - smooth).max()
    assert 1e-4 < difference < 0.05  # millimetres of texture, never a different motion

    def hf(j):
        return np.abs(np.diff(j, n=3, axis=0)).mean()

    assert hf(textured[:, [0, 20, 21]]) > 1.5 * hf(smooth[:, [0, 20, 21]])
    bones = np.linalg.norm(textured[:, 1:] - textured[:, T2M.parents[1:]], axis=-1)
    assert np.ptp(bones, axis=0).max() < 1e-4
