"""SC-SfMLearner depth/pose nets: checkpoint-compatible layout, outputs, checkpoints, batched inference."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from torch import nn

from core.errors import ConfigError, InputError
from core.geometry import pose_vec_to_mat
from pipeline.nets import (
    DepthPoseRunner,
    DispResNet,
    PoseResNet,
    ResNet,
    load_depth_net,
    load_imagenet_encoder,
    load_pose_net,
    normalize_image,
    resolve_device,
    save_checkpoint,
)
from pipeline.nets.checkpoint import detect_resnet_layers

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures"
H, W = 64, 128


def fixture_keys(name: str) -> list[list]:
    doc = json.loads((FIXTURES / name).read_text())
    assert doc["num_keys"] == len(doc["keys"])
    return doc["keys"]


def layout(net: nn.Module) -> list[list]:
    return [[k, list(v.shape)] for k, v in net.state_dict().items()]


@pytest.fixture(scope="module", autouse=True)
def one_thread():
    """Tiny inputs gain nothing from threads, and OpenMP spinning on a shared 2-core box costs ~20×."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def depth18() -> DispResNet:
    torch.manual_seed(0)
    return DispResNet(18).eval()


@pytest.fixture(scope="module")
def pose18() -> PoseResNet:
    torch.manual_seed(1)
    return PoseResNet(18).eval()


def frames(n: int, seed: int, h: int = H, w: int = W) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, size=(n, h, w, 3), dtype=np.uint8)


# --------------------------------------------------------------------------- layout


def test_dispresnet18_state_dict_matches_official_layout(depth18):
    expected = fixture_keys("sc_sfm_dispresnet18_keys.json")
    assert len(expected) == 150  # torchvision resnet18: 122 (20 BN × 5, 20 convs, fc ×2) + 14 decoder convs × 2
    assert layout(depth18) == expected


def test_poseresnet18_state_dict_matches_official_layout(pose18):
    expected = fixture_keys("sc_sfm_poseresnet18_keys.json")
    assert len(expected) == 130  # 122 encoder + 4 head convs × 2
    assert layout(pose18) == expected
    assert pose18.state_dict()["encoder.encoder.conv1.weight"].shape == (64, 6, 7, 7)


def test_dispresnet50_state_dict_matches_official_layout():
    expected = fixture_keys("sc_sfm_dispresnet50_keys.json")
    assert len(expected) == 348  # torchvision resnet50: 320 (53 BN × 5, 53 convs, fc ×2) + 28 decoder
    net = DispResNet(50)
    assert layout(net) == expected
    assert net.encoder.num_ch_enc == (64, 256, 512, 1024, 2048)
    block = net.encoder.encoder.layer2[0]  # torchvision's "v1.5": the stride sits on the 3×3 conv
    assert block.conv1.stride == (1, 1) and block.conv2.stride == (2, 2) and block.downsample[0].stride == (2, 2)


def test_encoder_parameter_counts_equal_torchvision():
    # torchvision's published sizes: resnet18 11,689,512 and resnet50 25,557,032 parameters.
    assert sum(p.numel() for p in ResNet(18).parameters()) == 11_689_512
    assert sum(p.numel() for p in ResNet(50).parameters()) == 25_557_032


def test_encoder_initialised_like_torchvision(depth18):
    sd = depth18.state_dict()
    w = sd["encoder.encoder.layer4.0.conv1.weight"]  # 256 → 512: kaiming normal with fan_out = 512·3·3
    assert float(w.mean()) == pytest.approx(0.0, abs=1e-3)
    assert float(w.std()) == pytest.approx(math.sqrt(2.0 / (512 * 9)), rel=0.01)  # fan_in would give √2 more
    for k, v in sd.items():
        if k.startswith("encoder.") and (".bn" in k or ".downsample.1." in k):
            if k.endswith(".weight"):
                assert torch.all(v == 1), k
            elif k.endswith(".bias"):
                assert torch.all(v == 0), k


# --------------------------------------------------------------------------- outputs


def test_normalize_image_known_values():
    x = torch.tensor([0, 255, 114], dtype=torch.uint8)
    y = normalize_image(x)
    assert y.dtype == torch.float32
    assert y.tolist() == pytest.approx([-2.0, (1.0 - 0.45) / 0.225, (114 / 255 - 0.45) / 0.225], abs=1e-6)


def test_dispresnet_multiscale_in_training_and_finest_in_eval():
    torch.manual_seed(2)
    net = DispResNet(18)
    x = torch.randn(2, 3, H, W)
    net.train()
    outs = net(x)
    assert [tuple(o.shape) for o in outs] == [(2, 1, 64, 128), (2, 1, 32, 64), (2, 1, 16, 32), (2, 1, 8, 16)]
    sum(o.mean() for o in outs).backward()  # the graph is intact (in-place ELU/ReLU are safe)
    assert net.decoder.decoder[13].conv.weight.grad is not None
    net.eval()
    with torch.no_grad():
        disp = net(x)
    assert disp.shape == (2, 1, H, W)
    assert torch.all(disp >= 0.01) and torch.all(disp <= 10.01)
    assert torch.all(1.0 / disp > 0)


def test_disp_range_limits_are_exact():
    torch.manual_seed(3)
    net = DispResNet(18).eval()
    head = net.decoder.decoder[10].conv  # finest-scale disparity head
    x = torch.randn(1, 3, H, W)
    with torch.no_grad():
        head.weight.zero_()
        head.bias.fill_(1e4)
        hi = net(x)
        head.bias.fill_(-1e4)
        lo = net(x)
        head.bias.fill_(0.0)
        mid = net(x)
    assert torch.allclose(hi, torch.full_like(hi, 10.01), atol=1e-6)
    assert torch.allclose(lo, torch.full_like(lo, 0.01), atol=1e-7)
    assert torch.allclose(mid, torch.full_like(mid, 5.01), atol=1e-6)  # 10·sigmoid(0) + 0.01


def reference_decoder(sd: dict, feats: list[torch.Tensor]) -> list[torch.Tensor]:
    """SC-SfMLearner's decoder written functionally from its description, addressed by state-dict key."""

    def conv(x, name):  # reflection pad 1 + 3×3 conv
        return F.conv2d(F.pad(x, (1, 1, 1, 1), mode="reflect"), sd[name + ".weight"], sd[name + ".bias"])

    x, disps = feats[4], {}
    for i in (4, 3, 2, 1, 0):
        x = F.elu(conv(x, f"decoder.decoder.{2 * (4 - i)}.conv.conv"))
        x = F.interpolate(x, scale_factor=2, mode="nearest")
        if i > 0:
            x = torch.cat([x, feats[i - 1]], 1)
        x = F.elu(conv(x, f"decoder.decoder.{2 * (4 - i) + 1}.conv.conv"))
        if i < 4:
            disps[i] = 10 * torch.sigmoid(conv(x, f"decoder.decoder.{10 + i}.conv")) + 0.01
    return [disps[s] for s in range(4)]


def test_decoder_matches_functional_reference():
    torch.manual_seed(15)
    net = DispResNet(18).train()
    x = torch.randn(1, 3, H, W)
    with torch.no_grad():
        feats = net.encoder(x)
        sizes = [tuple(f.shape[1:]) for f in feats]
        assert sizes == [(64, 32, 64), (64, 16, 32), (128, 8, 16), (256, 4, 8), (512, 2, 4)]
        got = net(x)
        want = reference_decoder(net.state_dict(), feats)
    for g, w in zip(got, want):
        assert torch.allclose(g, w, atol=1e-6)


def test_dispresnet_rejects_size_not_multiple_of_32(depth18):
    with pytest.raises(ValueError, match="divisible by 32"):
        depth18(torch.zeros(1, 3, 60, 128))


def test_dispresnet50_forward():
    torch.manual_seed(4)
    net = DispResNet(50).eval()
    with torch.no_grad():
        disp = net(torch.randn(1, 3, H, W))
    assert disp.shape == (1, 1, H, W)
    assert torch.all(disp >= 0.01) and torch.all(disp <= 10.01)


def test_pose_output_is_hundredth_of_head_mean(pose18):
    a, b = torch.randn(2, 3, H, W), torch.randn(2, 3, H, W)
    with torch.no_grad():
        vec = pose18(a, b)
        # the same computation by hand: head convs with ReLU between, spatial mean, × 0.01
        f = pose18.encoder(torch.cat([a, b], 1))[-1]
        convs = pose18.decoder.net
        raw = convs[3](torch.relu(convs[2](torch.relu(convs[1](torch.relu(convs[0](f)))))))
    assert vec.shape == (2, 6)
    assert torch.allclose(vec, 0.01 * raw.mean(dim=(2, 3)), atol=1e-7)
    assert not torch.allclose(vec, pose18(b, a))  # order matters: pose_net(a, b) is T_{a→b}


def test_pose_bias_only_gives_hundredth_of_bias():
    torch.manual_seed(5)
    net = PoseResNet(18).eval()
    last = net.decoder.net[3]
    with torch.no_grad():
        last.weight.zero_()
        last.bias.copy_(torch.tensor([50.0, -20.0, 100.0, 1.0, 2.0, -3.0]))
        vec = net(torch.randn(3, 3, H, W), torch.randn(3, 3, H, W))
    assert torch.allclose(vec, torch.tensor([[0.5, -0.2, 1.0, 0.01, 0.02, -0.03]] * 3), atol=1e-6)


# --------------------------------------------------------------------------- checkpoints


def test_official_format_with_module_prefix_loads_strict(tmp_path, depth18):
    path = tmp_path / "dispnet_model_best.pth.tar"
    torch.save({"epoch": 7, "state_dict": {"module." + k: v for k, v in depth18.state_dict().items()}}, path)
    net = load_depth_net(path)
    assert isinstance(net, DispResNet) and net.num_layers == 18 and not net.training
    for (k, v), (k2, v2) in zip(depth18.state_dict().items(), net.state_dict().items()):
        assert k == k2 and torch.equal(v, v2)
    x = torch.randn(1, 3, H, W)
    with torch.no_grad():
        assert torch.equal(net(x), depth18(x))


def test_raw_state_dict_pose_checkpoint_loads(tmp_path, pose18):
    path = tmp_path / "exp_pose.pth"
    torch.save(pose18.state_dict(), path)
    net = load_pose_net(path, resnet_layers=18)
    a, b = torch.randn(1, 3, H, W), torch.randn(1, 3, H, W)
    with torch.no_grad():
        assert torch.equal(net(a, b), pose18(a, b))


def test_checkpoint_without_num_batches_tracked_loads(tmp_path, depth18):
    path = tmp_path / "old.pth"
    state = {k: v for k, v in depth18.state_dict().items() if not k.endswith("num_batches_tracked")}
    torch.save({"epoch": 1, "state_dict": state}, path)
    net = load_depth_net(path)
    assert torch.equal(net.state_dict()["encoder.encoder.conv1.weight"], state["encoder.encoder.conv1.weight"])


def test_save_checkpoint_round_trip_is_official_format_and_atomic(tmp_path, depth18):
    path = tmp_path / "sub" / "dispnet_checkpoint.pth.tar"
    save_checkpoint(path, nn.DataParallel(depth18), epoch=3)  # the wrapper's 'module.' is not saved
    raw = torch.load(path, weights_only=True)
    assert set(raw) == {"epoch", "state_dict"} and raw["epoch"] == 3
    assert list(raw["state_dict"]) == list(depth18.state_dict())
    assert [p.name for p in path.parent.iterdir()] == [path.name]  # no temporary left behind
    save_checkpoint(path, depth18, epoch=4)  # overwrite in place
    assert torch.load(path, weights_only=True)["epoch"] == 4
    net = load_depth_net(path)
    assert torch.equal(net.state_dict()["decoder.decoder.13.conv.weight"], depth18.decoder.decoder[13].conv.weight)


def test_mismatched_checkpoint_gives_one_line_error_naming_file_and_keys(tmp_path, depth18):
    state = dict(depth18.state_dict())
    del state["decoder.decoder.13.conv.bias"]
    state["decoder.decoder.14.conv.weight"] = torch.zeros(1, 16, 3, 3)
    state["decoder.decoder.10.conv.weight"] = torch.zeros(2, 16, 3, 3)
    path = tmp_path / "bad_disp.pth.tar"
    torch.save({"epoch": 1, "state_dict": state}, path)
    with pytest.raises(InputError) as err:
        load_depth_net(path)
    msg = str(err.value)
    assert "\n" not in msg
    assert msg.startswith(str(path) + ": state dict does not match DispResNet-18")
    assert "1 missing keys (decoder.decoder.13.conv.bias)" in msg
    assert "1 unexpected keys (decoder.decoder.14.conv.weight)" in msg
    assert "decoder.decoder.10.conv.weight: file (2, 16, 3, 3) vs net (1, 16, 3, 3)" in msg


def test_pose_checkpoint_given_to_depth_loader_is_rejected(tmp_path, pose18):
    path = tmp_path / "exp_pose_model_best.pth.tar"
    torch.save({"epoch": 1, "state_dict": pose18.state_dict()}, path)
    with pytest.raises(InputError) as err:
        load_depth_net(path)
    msg = str(err.value)
    assert "\n" not in msg and "exp_pose_model_best.pth.tar" in msg
    assert "28 missing keys (decoder.decoder.0.conv.conv.weight" in msg and "(+24 more)" in msg
    assert "8 unexpected keys (decoder.net.0.weight" in msg
    assert "encoder.encoder.conv1.weight: file (64, 6, 7, 7) vs net (64, 3, 7, 7)" in msg


@pytest.mark.parametrize(
    "content, problem",
    [(b"this is not a checkpoint", "not a readable checkpoint"), (b"", "not a readable checkpoint")],
)
def test_corrupt_file_is_input_error(tmp_path, content, problem):
    path = tmp_path / "broken.pth"
    path.write_bytes(content)
    with pytest.raises(InputError, match=problem) as err:
        load_depth_net(path)
    assert "\n" not in str(err.value)


def test_missing_file_and_non_tensor_entries_are_input_errors(tmp_path):
    with pytest.raises(InputError, match="no such checkpoint file"):
        load_pose_net(tmp_path / "nope.pth")
    path = tmp_path / "weird.pth"
    torch.save({"state_dict": {"encoder.encoder.conv1.weight": 3}}, path)
    with pytest.raises(InputError, match="is a int, not a tensor"):
        load_pose_net(path)


def test_resnet_depth_detected_from_keys(depth18):
    keys50 = {k: torch.zeros(0) for k, _ in fixture_keys("sc_sfm_dispresnet50_keys.json")}
    assert detect_resnet_layers(keys50) == 50
    assert detect_resnet_layers(depth18.state_dict()) == 18


def test_imagenet_encoder_init_tiles_conv1_for_pose(tmp_path):
    torch.manual_seed(6)
    imagenet = ResNet(18)
    path = tmp_path / "resnet18-f37072fd.pth"
    torch.save(imagenet.state_dict(), path)
    pose = PoseResNet(18)
    load_imagenet_encoder(pose, path)
    w = imagenet.conv1.weight
    assert torch.allclose(pose.encoder.encoder.conv1.weight, torch.cat([w, w], 1) / 2)
    assert torch.equal(pose.encoder.encoder.layer3[1].bn2.running_var, imagenet.layer3[1].bn2.running_var)
    assert torch.equal(pose.encoder.encoder.fc.weight, imagenet.fc.weight)
    depth = DispResNet(18)
    load_imagenet_encoder(depth, path)
    assert torch.equal(depth.encoder.encoder.conv1.weight, w)


# --------------------------------------------------------------------------- inference


def test_runner_depth_is_inverse_disp_and_counts_calls(depth18):
    runner = DepthPoseRunner(depth18, None, device="cpu", batch_size=2)
    imgs = frames(5, seed=7)
    depth = runner.depth(imgs)
    assert depth.shape == (5, H, W) and depth.dtype == np.float32
    assert (runner.depth_images, runner.depth_forwards) == (5, 3)
    with torch.no_grad():
        x = normalize_image(torch.from_numpy(imgs).permute(0, 3, 1, 2))
        expected = (1.0 / depth18(x))[:, 0].numpy()
    np.testing.assert_allclose(depth, expected, rtol=1e-5)
    assert np.all(depth > 1.0 / 10.01 - 1e-6) and np.all(depth < 1.0 / 0.01 + 1e-3)
    runner.reset_counters()
    assert runner.depth_images == 0


def test_runner_is_deterministic_and_batch_size_independent(depth18):
    imgs = frames(3, seed=8)
    a = DepthPoseRunner(depth18, None, device="cpu", batch_size=3).depth(imgs)
    b = DepthPoseRunner(depth18, None, device="cpu", batch_size=3).depth(imgs)
    c = DepthPoseRunner(depth18, None, device="cpu", batch_size=1).depth(imgs)
    assert np.array_equal(a, b)
    np.testing.assert_allclose(a, c, rtol=1e-4)
    torch.manual_seed(0)
    again = DispResNet(18)
    for (k, v), v2 in zip(depth18.state_dict().items(), again.state_dict().values()):
        assert torch.equal(v, v2), k  # same seed → same initial weights


def test_runner_pose_is_tgt_to_ref_matrix(pose18):
    runner = DepthPoseRunner(None, pose18, device="cpu", batch_size=2)
    img_t, img_t1 = frames(3, seed=9), frames(3, seed=10)
    T = runner.pose(img_t, img_t1)
    assert T.shape == (3, 4, 4) and T.dtype == np.float64
    assert (runner.pose_pairs, runner.pose_forwards) == (3, 2)
    with torch.no_grad():
        norm = lambda im: normalize_image(torch.from_numpy(im).permute(0, 3, 1, 2))  # noqa: E731
        vec = pose18(norm(img_t), norm(img_t1)).double().numpy()
    np.testing.assert_allclose(T, pose_vec_to_mat(vec), atol=1e-6)
    np.testing.assert_allclose(T[:, 3], [[0, 0, 0, 1]] * 3)


def test_runner_pose_hand_computed_matrix():
    torch.manual_seed(11)
    net = PoseResNet(18)
    with torch.no_grad():
        net.decoder.net[3].weight.zero_()
        # t = (0.5, −0.2, 1.0); rx = π/2, ry = 0, rz = π/2 (× 0.01 of the head's bias)
        net.decoder.net[3].bias.copy_(torch.tensor([50.0, -20.0, 100.0, 50 * math.pi, 0.0, 50 * math.pi]))
    T = DepthPoseRunner(None, net, device="cpu").pose(frames(1, seed=12), frames(1, seed=13))[0]
    # R = Rx(90°)·Rz(90°) = [[0,−1,0],[0,0,−1],[1,0,0]]  (Rz·Rx would be [[0,0,1],[1,0,0],[0,1,0]])
    expected = np.array([[0, -1, 0, 0.5], [0, 0, -1, -0.2], [1, 0, 0, 1.0], [0, 0, 0, 1]], dtype=np.float64)
    np.testing.assert_allclose(T, expected, atol=2e-6)


def test_runner_input_checks(depth18, pose18):
    runner = DepthPoseRunner(depth18, pose18, device="cpu")
    with pytest.raises(ValueError, match="uint8"):
        runner.depth(frames(1, seed=0).astype(np.float32))
    with pytest.raises(ConfigError, match="multiples of 32"):
        runner.depth(frames(1, seed=0, h=60))
    with pytest.raises(ValueError, match="differ in shape"):
        runner.pose(frames(2, seed=0), frames(1, seed=1))
    with pytest.raises(ConfigError, match="no depth net"):
        DepthPoseRunner(None, pose18, device="cpu").depth(frames(1, seed=0))


def test_runner_amp_on_cpu_stays_close(depth18):
    imgs = frames(1, seed=14)
    full = DepthPoseRunner(depth18, None, device="cpu").depth(imgs)
    amp = DepthPoseRunner(depth18, None, device="cpu", amp=True).depth(imgs)
    assert amp.dtype == np.float32
    assert np.median(np.abs(amp - full) / full) < 0.02


def test_resolve_device():
    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")
    with pytest.raises(ConfigError):
        resolve_device("tpu")
    if not torch.cuda.is_available():
        with pytest.raises(ConfigError, match="CUDA is not available"):
            resolve_device("cuda")
