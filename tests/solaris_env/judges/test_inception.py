"""The FID InceptionV3 (solaris_env.judges.inception) on a random checkpoint the tests write themselves."""

import numpy as np
import pytest
import torch
from torch import nn

from solaris_env.judges.features import frechet_distance
from solaris_env.judges.inception import (
    POOL3_DIM,
    FIDInceptionV3,
    InceptionFeatures,
    _avg_pool_keep,
    _max_pool_keep,
    load_fid_inception,
    load_fid_state_dict,
)

# pytorch-fid's FID Inception without its fc = torchvision's inception_v3 (27,161,264 parameters) less its
# 1000-class fc (2048 * 1000 + 1000) and AuxLogits (768*128 + 2*128 + 128*768*25 + 2*768 + 768*1000 + 1000);
# the same as Keras' InceptionV3(include_top=False): 21,802,784 = convs + BN beta + BN moving mean/var.
FID_INCEPTION_PARAMS = 27_161_264 - (2048 * 1000 + 1000) - (98_560 + 2_459_136 + 769_000)
BN_RUNNING_STATS = 34_432  # running mean + var of all 17,216 BatchNorm channels (Keras' non-trainable count)
FC_CLASSES = 1008  # the weights file's classifier (ignored)
BATCH = 2  # frames per forward: a 299x299 forward costs ~6 GFLOP per frame on CPU
SIZE = 64  # our frames
FD_DIMS = 256  # Fréchet distances on the first FD_DIMS features: a 2048-d one costs ~20 s on a busy 2-core CPU


def random_fid_state(seed: int = 0) -> dict[str, torch.Tensor]:
    """A seeded random FID Inception state dict, scaled so activations neither vanish nor explode,
    plus a random 1008-class fc as in the real weights file."""
    torch.manual_seed(seed)
    net = FIDInceptionV3()
    for m in net.modules():
        if isinstance(m, nn.Conv2d):
            nn.init.kaiming_normal_(m.weight, nonlinearity="relu")
        elif isinstance(m, nn.BatchNorm2d):
            nn.init.uniform_(m.weight, 0.5, 1.5)
            nn.init.normal_(m.bias, std=0.1)
            m.running_mean.normal_(std=0.1)
            m.running_var.uniform_(0.5, 1.5)
    state = dict(net.state_dict())
    state["fc.weight"] = torch.randn(FC_CLASSES, POOL3_DIM)
    state["fc.bias"] = torch.randn(FC_CLASSES)
    return state


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    state = random_fid_state()
    path = tmp_path_factory.mktemp("inception") / "pt_inception.pth"
    torch.save(state, path)
    return path, state


@pytest.fixture(scope="module")
def features(checkpoint):
    return InceptionFeatures.load(checkpoint[0], batch_size=BATCH)


@pytest.fixture(scope="module")
def frames():
    return np.random.default_rng(0).integers(0, 256, (3, SIZE, SIZE, 3), dtype=np.uint8)


@pytest.fixture(scope="module")
def feats(features, frames):
    return features(frames)


def test_architecture_has_the_fid_inception_parameters_and_keys():
    net = FIDInceptionV3()
    assert FID_INCEPTION_PARAMS == 21_785_568
    assert sum(p.numel() for p in net.parameters()) == FID_INCEPTION_PARAMS
    state = net.state_dict()
    assert sum(v.numel() for k, v in state.items() if k.endswith(("running_mean", "running_var"))) == BN_RUNNING_STATS
    shapes = {"Conv2d_1a_3x3.conv.weight": (32, 3, 3, 3), "Conv2d_4a_3x3.bn.running_var": (192,),
              "Mixed_5b.branch_pool.conv.weight": (32, 192, 1, 1),
              "Mixed_5d.branch5x5_2.conv.weight": (64, 48, 5, 5),
              "Mixed_6a.branch3x3.conv.weight": (384, 288, 3, 3),
              "Mixed_6b.branch7x7_1.conv.weight": (128, 768, 1, 1),
              "Mixed_6e.branch7x7dbl_2.conv.weight": (192, 192, 7, 1),
              "Mixed_7a.branch7x7x3_2.conv.weight": (192, 192, 1, 7),
              "Mixed_7b.branch3x3dbl_3b.conv.weight": (384, 384, 3, 1),
              "Mixed_7c.branch_pool.conv.weight": (192, 2048, 1, 1)}
    for key, shape in shapes.items():
        assert tuple(state[key].shape) == shape, key
    assert not any(k.startswith(("fc.", "AuxLogits.")) for k in state)
    # FID pools: padded zeros are not averaged; Mixed_7c max-pools in its pool branch, Mixed_7b averages
    ones = torch.ones(1, 1, 4, 4)
    assert torch.equal(_avg_pool_keep(ones), ones)
    assert net.Mixed_7b.pool is _avg_pool_keep and net.Mixed_7c.pool is _max_pool_keep


def test_loaded_network_holds_the_checkpoint_in_eval_mode(features, checkpoint):
    _, state = checkpoint
    net = features.net
    assert not net.training and not any(p.requires_grad for p in net.parameters())
    for key, value in net.state_dict().items():
        assert torch.equal(value, state[key]), key


def test_features_are_finite_deterministic_and_independent_of_the_batch(features, frames, feats):
    assert feats.shape == (len(frames), POOL3_DIM) and feats.dtype == np.float64
    assert np.isfinite(feats).all() and (feats >= 0).all() and feats.std(axis=0).max() > 0  # post-ReLU means
    np.testing.assert_array_equal(features(frames), feats)
    # frame 1 alone (padded with a zero frame) vs second in the first chunk, next to frame 0
    np.testing.assert_array_equal(features(frames[1:2]), feats[1:2])
    assert features(np.zeros((0, SIZE, SIZE, 3), np.uint8)).shape == (0, POOL3_DIM)
    with pytest.raises(ValueError, match="uint8"):
        features(frames.astype(np.float32))


def test_fid_of_a_set_with_itself_is_zero_and_positive_for_a_perturbed_set(features, frames, feats):
    brighter = (frames // 2 + 128).astype(np.uint8)
    f, g = feats[:, :FD_DIMS], features(brighter)[:, :FD_DIMS]
    fid = frechet_distance(f, g)
    assert fid > 0
    assert frechet_distance(f, f) == pytest.approx(0.0, abs=1e-6 * fid)


def test_bad_state_dicts_raise_naming_the_key(checkpoint, tmp_path):
    _, state = checkpoint
    missing = {k: v for k, v in state.items() if k != "Mixed_6c.branch1x1.bn.running_mean"}
    path = tmp_path / "missing.pth"
    torch.save(missing, path)
    with pytest.raises(ValueError, match=r"missing key 'Mixed_6c\.branch1x1\.bn\.running_mean'"):
        load_fid_inception(path)
    with pytest.raises(ValueError, match=r"unexpected key 'AuxLogits\.fc\.weight'"):
        load_fid_state_dict(FIDInceptionV3(), {**state, "AuxLogits.fc.weight": torch.zeros(1008, 768)})
    wrong = {**state, "Mixed_7c.branch_pool.conv.weight": torch.zeros(192, 1280, 1, 1)}
    with pytest.raises(ValueError, match=r"'Mixed_7c\.branch_pool\.conv\.weight' has shape \(192, 1280, 1, 1\)"):
        load_fid_state_dict(FIDInceptionV3(), wrong)
    with pytest.raises(ValueError, match="expected a state dict"):
        load_fid_state_dict(FIDInceptionV3(), [state])
    with pytest.raises(FileNotFoundError, match="pt_inception-2015-12-05-6726825d.pth"):
        load_fid_inception(tmp_path / "absent.pth")
    # BatchNorm step counters are optional (unused in eval mode); fc.* is accepted and ignored
    no_counters = {k: v for k, v in state.items() if not k.endswith(".num_batches_tracked")}
    net = load_fid_state_dict(FIDInceptionV3(), no_counters)
    assert torch.equal(net.Mixed_7c.branch_pool.conv.weight, state["Mixed_7c.branch_pool.conv.weight"])
