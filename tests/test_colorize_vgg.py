"""VGG extractor: torchvision's architecture, relu3_x/relu4_x blocks, ImageNet normalisation, random-weights flag."""
import pytest
import torch
from torch import nn

from arcsem.colorize.vgg import IMAGENET_MEAN, IMAGENET_STD, VGGFeatures


@pytest.fixture
def offline(tmp_path, monkeypatch):
    monkeypatch.setenv("ARCSEM_OFFLINE", "1")
    monkeypatch.setenv("TORCH_HOME", str(tmp_path))  # an empty hub cache


def test_vgg16_blocks_shapes_normalisation(offline, caplog):
    with caplog.at_level("WARNING", logger="arcsem.colorize.vgg"):
        v = VGGFeatures("vgg16")
    assert v.features_source == "random"
    # one warning (the log only, not also a Python warning), naming what metrics.json records
    warned = [r.getMessage() for r in caplog.records if "RANDOM weights" in r.getMessage()]
    assert len(warned) == 1 and "'features: vgg16-random'" in warned[0]
    # torchvision vgg16.features: relu3_1..3 = 11, 13, 15; relu4_1..3 = 18, 20, 22
    assert v.layers == {3: [11, 13, 15], 4: [18, 20, 22]}
    assert isinstance(v.trunk[10], nn.Conv2d) and v.trunk[10].in_channels == 128 and v.trunk[10].out_channels == 256
    assert len(v.trunk) == 23
    torch.testing.assert_close(v.mean.flatten(), torch.tensor(IMAGENET_MEAN))
    torch.testing.assert_close(v.std.flatten(), torch.tensor(IMAGENET_STD))
    x = torch.rand(2, 32, 48, 3, requires_grad=True)
    f3, f4 = v(x)
    assert f3.shape == (2, 768, 8, 12) and f4.shape == (2, 1536, 4, 6)
    manual = v.trunk[:12]((x.permute(0, 3, 1, 2) - v.mean) / v.std)  # relu3_1 by hand
    torch.testing.assert_close(f3[:, :256], manual)
    f4.sum().backward()
    assert x.grad is not None and all(p.grad is None for p in v.parameters())


def test_vgg19_layers(offline):
    v = VGGFeatures("vgg19")
    assert v.layers == {3: [11, 13, 15, 17], 4: [20, 22, 24, 26]}
    f3, f4 = v(torch.rand(1, 32, 32, 3))
    assert f3.shape[1] == 1024 and f4.shape[1] == 2048


def test_weights_from_hub_cache_are_loaded(offline, tmp_path):
    donor = VGGFeatures("vgg16")
    sd = {f"features.{k}": t + 0.5 for k, t in donor.trunk.state_dict().items()}
    sd["classifier.0.weight"] = torch.zeros(1)  # extra keys of the full model are ignored
    (tmp_path / "hub" / "checkpoints").mkdir(parents=True)
    torch.save(sd, tmp_path / "hub" / "checkpoints" / "vgg16-397923af.pth")
    v = VGGFeatures("vgg16")
    assert v.features_source == "imagenet"
    torch.testing.assert_close(v.trunk[0].weight, sd["features.0.weight"])


@pytest.mark.parametrize("arch", ["vgg16", "vgg19"])
def test_layers_are_torchvisions_without_importing_it(offline, arch):
    """Our layer list is torchvision's vgg.features module for module (so its checkpoints load by index) and, built
    from the same random state, weight for weight (runs with random weights keep their features); building the
    extractor imports no torchvision (seconds a process; stage 2 needs it for nothing else when LPIPS is off)."""
    import subprocess
    import sys

    from arcsem.colorize.vgg import vgg_layers
    from arcsem.tvfix import import_torchvision

    tv = import_torchvision()
    torch.manual_seed(3)
    theirs = tv.models.vgg.make_layers(tv.models.vgg.cfgs[{"vgg16": "D", "vgg19": "E"}[arch]], batch_norm=False)
    torch.manual_seed(3)
    ours = vgg_layers(arch)
    assert [repr(m) for m in ours] == [repr(m) for m in theirs]
    for (k, a), (k2, b) in zip(ours.state_dict().items(), theirs.state_dict().items(), strict=True):
        assert k == k2 and torch.equal(a, b), k
    code = (f"import sys; from arcsem.colorize.vgg import VGGFeatures; VGGFeatures('{arch}'); "
            "print('torchvision' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip().splitlines()[-1] == "False", out.stdout + out.stderr



def test_random_weights_are_the_same_in_every_process_whatever_ran_before(offline):
    """Without ImageNet weights the trunk keeps its initial weights: drawn from a fixed seed, so two extractors built
    after different random draws (two jobs of one multirun worker, two runs) are the same function, and building
    one leaves the global random state as it was."""
    torch.manual_seed(1)
    a = VGGFeatures("vgg16")
    torch.rand(1000)
    state = torch.random.get_rng_state()
    b = VGGFeatures("vgg16")
    assert torch.equal(torch.random.get_rng_state(), state)
    assert a.features_source == "random" and a.key() == b.key()
    for (k, x), (_, y) in zip(a.trunk.state_dict().items(), b.trunk.state_dict().items(), strict=True):
        assert torch.equal(x, y), k


def test_trunk_sees_nchw_memory_whatever_the_input_layout(offline):
    """A render ``[C, H, W, 3]`` permuted to NCHW is channels-last in memory; the trunk's first convolution gets it
    NCHW-contiguous, as its weights are (the mismatch ran 1.6x slower forward and backward on oneDNN,
    benchmarks/vgg_layout.py), with the same features as an NCHW-stored copy of the image."""
    v = VGGFeatures("vgg16")
    seen = []
    v.trunk[0].register_forward_pre_hook(lambda m, args: seen.append(args[0].is_contiguous()))
    render = torch.rand(1, 24, 40, 3)  # channels last in memory
    stored_nchw = render.permute(0, 3, 1, 2).contiguous().permute(0, 2, 3, 1)  # the same image, NCHW in memory
    for f, g in zip(v(render), v(stored_nchw)):
        torch.testing.assert_close(f, g, rtol=1e-5, atol=1e-6)
    assert seen == [True, True]
