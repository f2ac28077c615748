"""The Judge API (shapes, resizing, errors), probe weights I/O, the shipped weights, and the train CLI."""

import json

import numpy as np
import pytest

from solaris_env.judges import DEFAULT_WEIGHTS, Judge, questions
from solaris_env.judges.config import ProbeConfig
from solaris_env.judges.probe import (
    load_probe,
    new_probe,
    num_params,
    read_metadata,
    save_probe,
)
from solaris_env.judges.scoring import episode_accuracy, judge_episodes

SMALL = ProbeConfig(image_size=16, channels=(4, 8), hidden=8)
SHIPPED_MAX_BYTES = 5 * 2**20  # the shipped judges stay under 5 MB


@pytest.fixture(scope="module")
def small_judge():
    return Judge({name: new_probe(name, SMALL, seed=k) for k, name in enumerate(questions.QUESTIONS)})


def frames(n, size=64, seed=0):
    return np.random.default_rng(seed).integers(0, 256, (n, size, size, 3), dtype=np.uint8)


@pytest.mark.parametrize("question", sorted(questions.QUESTIONS))
def test_answers_are_words_of_the_question_one_per_query(small_judge, question):
    q = questions.get(question)
    batches = [frames(5, seed=k) for k in range(q.num_frames)]
    probs = small_judge.probabilities(question, *batches)
    assert probs.shape == (5, q.num_answers)
    np.testing.assert_allclose(probs.sum(-1), 1.0, rtol=1e-5)
    answers = small_judge.answer(question, *batches)
    assert len(answers) == 5 and set(answers) <= set(q.answers)
    assert answers == [q.answers[i] for i in probs.argmax(-1)]


def test_batches_single_frames_and_sizes_agree(small_judge):
    x = frames(70, size=SMALL.image_size)  # more than one jitted chunk
    batched = small_judge.probabilities("position", x)
    one = small_judge.probabilities("position", x[3])  # (H, W, 3) is a batch of one
    np.testing.assert_allclose(one[0], batched[3], rtol=1e-5, atol=1e-6)
    for n in (2, 3, 5, 33):  # padded to 2, 4, 8, 64: padding never leaks into the answers
        np.testing.assert_allclose(small_judge.probabilities("position", x[:n]), batched[:n], rtol=1e-5, atol=1e-6)
    big = np.repeat(np.repeat(x[:4], 4, axis=1), 4, axis=2)  # 64x64 -> resized back to 16x16 (INTER_AREA)
    np.testing.assert_allclose(small_judge.probabilities("position", big), batched[:4], rtol=1e-4, atol=1e-5)
    assert small_judge.probabilities("visible", frames(0)).shape == (0, 2)


def test_bad_calls_name_the_problem(small_judge):
    with pytest.raises(ValueError, match="unknown question 'colour'"):
        small_judge.answer("colour", frames(1))
    with pytest.raises(ValueError, match="motion takes 2 frame batch"):
        small_judge.answer("motion", frames(2))
    with pytest.raises(ValueError, match=r"frames\[0\] must be uint8"):
        small_judge.answer("visible", frames(2).astype(np.float32))
    with pytest.raises(ValueError, match="differ in length"):
        small_judge.answer("same_scenery", frames(2), frames(3))
    with pytest.raises(ValueError, match="no probe for 'motion'"):
        Judge({"visible": new_probe("visible", SMALL, 0)}).answer("motion", frames(1), frames(1))
    with pytest.raises(ValueError, match="takes 1 frames, the question 2"):
        Judge({"motion": new_probe("visible", SMALL, 0)})


def test_probe_files_round_trip_and_are_checked(tmp_path):
    probe = new_probe("motion", SMALL, seed=3)
    path = save_probe(tmp_path / "motion.safetensors", "motion", probe, {"note": "x"})
    assert read_metadata(path)["extra"] == {"note": "x"}
    name, loaded, extra = load_probe(path)
    assert name == "motion" and loaded.cfg == SMALL and extra == {"note": "x"}
    x = frames(2, size=16)[:, None].repeat(2, axis=1)
    np.testing.assert_array_equal(np.asarray(loaded(x)), np.asarray(probe(x)))
    assert not list(tmp_path.glob("*.tmp"))  # atomic write leaves no temp file
    judge = Judge.load(tmp_path, ["motion"])
    assert judge.questions == ["motion"]
    with pytest.raises(FileNotFoundError, match="no probe for 'visible'"):
        Judge.load(tmp_path, ["visible"])
    (tmp_path / "visible.safetensors").write_bytes(path.read_bytes())  # a motion probe under the wrong name
    with pytest.raises(ValueError, match="holds the probe of 'motion'"):
        Judge.load(tmp_path, ["visible"])


def test_shipped_weights_load_and_fit_the_budget():
    files = sorted(DEFAULT_WEIGHTS.glob("*.safetensors"))
    assert sorted(f.stem for f in files) == sorted(questions.QUESTIONS)
    assert sum(f.stat().st_size for f in files) < SHIPPED_MAX_BYTES
    judge = Judge.load()
    for name in questions.QUESTIONS:
        _, probe, extra = load_probe(DEFAULT_WEIGHTS / f"{name}.safetensors")
        assert probe.num_frames == questions.get(name).num_frames
        assert extra["params"] == num_params(probe) and extra["steps"] >= 1
    assert set(judge.questions) == set(questions.QUESTIONS)


def test_shipped_judge_passes_unseen_ground_truth_episodes(episodes):
    """The fixture's collect seed is neither the training nor the held-out seed: a fresh sample."""
    results = judge_episodes(Judge.load(), list(episodes.values()))
    wrong = [(r.episode, r.index, r.expected, r.answer) for r in results if not r.correct]
    assert not wrong
    assert all(s["accuracy"] == 1.0 for s in episode_accuracy(results).values())


def test_train_cli_writes_probes_and_resumes(collected, tmp_path, capsys):
    from solaris_env.judges import train

    out = tmp_path / "judges"
    args = ["--data", str(collected), "--out", str(out), "--steps", "2", "--batch-size", "4",
            "--questions", "visible"]
    assert train.main(args + ["--heldout", str(collected)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["report.json", "visible.safetensors"]
    report = json.loads((out / "report.json").read_text())
    assert set(report["frame_level"]) == {"visible"} and report["frame_level"]["visible"]["examples"] > 0
    assert set(report["episode_level"]) == {"oneLooksAwayEval"}
    before = (out / "visible.safetensors").stat().st_mtime_ns
    capsys.readouterr()
    assert train.main(args) == 0  # resume: the probe exists, nothing retrained
    assert (out / "visible.safetensors").stat().st_mtime_ns == before
    assert "training" not in capsys.readouterr().err


def test_evaluate_cli_scores_collected_episodes(collected, tmp_path, capsys):
    from solaris_env.judges import evaluate

    for k, name in enumerate(questions.QUESTIONS):
        save_probe(tmp_path / f"{name}.safetensors", name, new_probe(name, SMALL, seed=k))
    out = tmp_path / "scores.json"
    assert evaluate.main(["--data", str(collected), "--weights", str(tmp_path), "--out", str(out)]) == 0
    report = json.loads(out.read_text())
    assert set(report["episode_level"]) == {e.name for e in (collected / "eval").iterdir() if e.is_dir()}
    assert set(report["tasks"]) == {"Movement", "Grounding", "Building", "Consistency"}  # no bothLookAway collected
    assert "Movement" in capsys.readouterr().out
    with pytest.raises(SystemExit, match="needs --endpoint"):
        evaluate.main(["--data", str(collected), "--judge", "vlm"])


def test_late_fusion_answers_the_same_for_either_order():
    from dataclasses import replace

    late = replace(SMALL, fusion="late")
    judge = Judge({"same_scenery": new_probe("same_scenery", late, seed=0)})
    a, b = frames(6, size=16, seed=1), frames(6, size=16, seed=2)
    np.testing.assert_allclose(judge.probabilities("same_scenery", a, b), judge.probabilities("same_scenery", b, a),
                               rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match="late fusion compares two frames"):
        new_probe("visible", late, seed=0)
    with pytest.raises(ValueError, match="fusion must be one of"):
        ProbeConfig(fusion="middle")


def test_motion_probe_is_equivariant_to_playing_the_pair_backwards(tmp_path):
    """answer(b, a) is the reversed answer(a, b) (closer <-> farther, left <-> right) for any weights and
    inputs, also after a save / load; identical frames tie closer with farther and left with right."""
    from flax import nnx

    from solaris_env.judges.probe import Probe

    q = questions.get("motion")
    perm = q.reverse_permutation()
    assert [q.answers[i] for i in perm] == ["farther", "closer", "right", "left", "no motion"]
    assert questions.get("visible").reverse_permutation() is None
    a, b = frames(6, size=16, seed=3), frames(6, size=16, seed=4)
    for probe in (new_probe("motion", SMALL, seed=0),
                  load_probe(save_probe(tmp_path / "motion.safetensors", "motion", new_probe("motion", SMALL, 1)))[1]):
        assert probe.reverse_perm == perm
        judge = Judge({"motion": probe})
        np.testing.assert_allclose(judge.probabilities("motion", b, a), judge.probabilities("motion", a, b)[:, perm],
                                   rtol=1e-5, atol=1e-6)
        still = judge.probabilities("motion", a, a)
        i = {w: q.index(w) for w in q.answers}
        np.testing.assert_allclose(still[:, i["closer"]], still[:, i["farther"]], rtol=1e-5, atol=1e-7)
        np.testing.assert_allclose(still[:, i["left"]], still[:, i["right"]], rtol=1e-5, atol=1e-7)
    with pytest.raises(ValueError, match="reverse_perm needs a two-frame early-fusion probe"):
        Probe(SMALL, 1, 2, rngs=nnx.Rngs(0), reverse_perm=(1, 0))
    with pytest.raises(ValueError, match="reverse_perm must be a permutation"):
        Probe(SMALL, 2, 5, rngs=nnx.Rngs(0), reverse_perm=(0, 0, 1, 2, 3))
