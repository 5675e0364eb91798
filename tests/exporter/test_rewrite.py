"""The ConvTranspose -> Conv + PixelShuffle rewrite is exact."""
import pytest
import torch
from torch import nn

from exporter.rewrite import ConvTransposeAsConv, is_rewritable, rewrite_conv_transpose


@pytest.mark.parametrize("cin, cout, bias, hw", [(3, 5, True, (4, 6)), (8, 2, False, (1, 1)), (1, 1, True, (7, 3))])
def test_single_layer_exact(cin, cout, bias, hw):
    torch.manual_seed(0)
    convt = nn.ConvTranspose2d(cin, cout, 4, stride=2, padding=1, bias=bias)
    x = torch.randn(2, cin, *hw)
    with torch.no_grad():
        ref = convt(x)
        out = ConvTransposeAsConv(convt)(x)
    assert out.shape == ref.shape == (2, cout, 2 * hw[0], 2 * hw[1])
    assert (out - ref).abs().max().item() < 1e-5


def test_model_rewrite_counts_and_preserves_output():
    torch.manual_seed(1)
    model = nn.Sequential(nn.Conv2d(2, 4, 4, 2, 1), nn.ReLU(),
                          nn.ConvTranspose2d(4, 4, 4, 2, 1), nn.ReLU(),
                          nn.Sequential(nn.ConvTranspose2d(4, 3, 4, 2, 1)),
                          nn.ConvTranspose2d(3, 3, 3, 1, 1))  # not 4x4/s2: left alone
    new, n = rewrite_conv_transpose(model)
    assert n == 2
    assert isinstance(model[2], nn.ConvTranspose2d), "the original must not be modified"
    x = torch.randn(1, 2, 16, 16)
    with torch.no_grad():
        assert (new(x) - model(x)).abs().max().item() < 1e-5


def test_rejects_other_geometries():
    assert not is_rewritable(nn.ConvTranspose2d(2, 2, 4, stride=2, padding=0))
    with pytest.raises(ValueError, match="kernel 4, stride 2, padding 1"):
        ConvTransposeAsConv(nn.ConvTranspose2d(2, 2, 3, stride=2, padding=1))
