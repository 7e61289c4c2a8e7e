"""Networks trained for place recognition, rebuilt in plain torch with their published state-dict layouts, so
that a user's checkpoint loads as it is saved; each outputs one L2-normalised global descriptor (B, D).

* ``netvlad``: VGG16 cut after conv5_3 (no ReLU) + NetVLAD (Arandjelovic et al. 2016), the layout of the
  widely used PyTorch port (Nanne/pytorch-NetVlad): ``encoder.0.weight`` ... ``encoder.28.bias``,
  ``pool.conv.weight`` (K, 512, 1, 1; ``pool.conv.bias`` with its vladv2), ``pool.centroids`` (K, 512).
  Output K x 512 (32,768 for 64 clusters): input L2-normalised per cell, soft-assigned, residuals summed,
  intra-normalised, flattened, L2-normalised.
* ``cosplace`` / ``eigenplaces`` (Berton et al. 2022 / 2023; one architecture): a ResNet-18/50/101/152 cut
  before its pooling (``backbone.0`` conv1 ... ``backbone.7`` layer4) or VGG16's conv layers (``backbone.0``
  ... ``backbone.28``), then L2-normalisation per cell, GeM (``aggregation.1.p``), a linear layer
  (``aggregation.3.weight`` / ``.bias``) and L2-normalisation.
* ``mixvpr`` (Ali-bey et al. 2023): a ResNet cut after layer3 (``backbone.model.conv1`` ...
  ``backbone.model.layer3``; layer4 too when the checkpoint has it) + the MixVPR aggregator
  (``aggregator.mix.N.mix.{0,1,3}``, ``aggregator.channel_proj``, ``aggregator.row_proj``), whose mixers are
  sized for one feature-map size: the input size must give it (320x320 for the published models).
* ``gem``: any backbone tap of ``backbones`` (e.g. the bundled EfficientNet-Lite0's stage5, ImageNet
  weights) + GeM (p = 3) + L2-normalisation: a global front end from a network not trained for places.

Each architecture's sizes (clusters, ResNet depth, output dims, mixer depth) are read from the checkpoint's
shapes; ``check_fits`` lists the keys that do not fit. All take RGB normalised with ImageNet's mean and std.
"""
from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from vpr_edge_export.backbones import RESNETS, NamedParts, resnet_channels, resnet_parts, vgg16_features

IMAGENET = ((0.485, 0.456, 0.406), (0.229, 0.224, 0.225))


# ------------------------------------------------------------------------------------------------ pieces
class L2Norm(nn.Module):
    """L2-normalisation along ``dim`` (1: the channels of a map, or a descriptor's entries)."""

    def __init__(self, dim: int = 1) -> None:
        super().__init__()
        self.dim = dim

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # noqa: D102
        return F.normalize(x, p=2.0, dim=self.dim)


class GeM(nn.Module):
    """Generalised-mean pooling over a map (B, C, h, w) -> (B, C, 1, 1): (mean(max(x, eps)^p))^(1/p)."""

    def __init__(self, p: float = 3.0, eps: float = 1e-6) -> None:
        super().__init__()
        self.p = nn.Parameter(torch.ones(1) * p)
        self.eps = eps

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # noqa: D102
        return x.clamp(min=self.eps).pow(self.p).mean(dim=(-2, -1), keepdim=True).pow(1.0 / self.p)


class Flatten(nn.Module):
    def forward(self, x: torch.Tensor) -> torch.Tensor:  # noqa: D102
        return x.flatten(1)


class NetVLAD(nn.Module):
    """NetVLAD over a map (B, D, h, w) -> (B, K * D): soft assignment by a 1x1 conv, residuals to the
    ``centroids`` (K, D) summed over the cells, intra- and then globally L2-normalised."""

    def __init__(self, clusters: int, dim: int, bias: bool = False) -> None:
        super().__init__()
        self.conv = nn.Conv2d(dim, clusters, 1, bias=bias)
        self.centroids = nn.Parameter(torch.rand(clusters, dim))

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # noqa: D102
        x = F.normalize(x, p=2.0, dim=1)
        a = F.softmax(self.conv(x).flatten(2), dim=1)                    # (B, K, N)
        cells = x.flatten(2)                                             # (B, D, N)
        vlad = torch.bmm(a, cells.transpose(1, 2)) - a.sum(dim=2).unsqueeze(2) * self.centroids   # (B, K, D)
        vlad = F.normalize(vlad, p=2.0, dim=2).flatten(1)
        return F.normalize(vlad, p=2.0, dim=1)


def vgg16_conv5_3() -> nn.Sequential:
    """torchvision VGG16's ``features`` up to conv5_3, without its ReLU (indices 0 ... 28)."""
    return nn.Sequential(*vgg16_features()[:29])


class MixerLayer(nn.Module):
    def __init__(self, dim: int, ratio: float) -> None:
        super().__init__()
        self.mix = nn.Sequential(nn.LayerNorm(dim), nn.Linear(dim, int(dim * ratio)), nn.ReLU(),
                                 nn.Linear(int(dim * ratio), dim))

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # noqa: D102
        return x + self.mix(x)


class MixVPR(nn.Module):
    """The MixVPR aggregator: (B, C, h, w) -> ``depth`` mixers over the h*w cells of each channel, a
    projection of the channels to ``out_channels`` and of the cells to ``out_rows`` -> (B, out_channels *
    out_rows), L2-normalised."""

    def __init__(self, in_channels: int, cells: int, out_channels: int, depth: int, ratio: float,
                 out_rows: int) -> None:
        super().__init__()
        self.mix = nn.Sequential(*[MixerLayer(cells, ratio) for _ in range(depth)])
        self.channel_proj = nn.Linear(in_channels, out_channels)
        self.row_proj = nn.Linear(cells, out_rows)

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # noqa: D102
        x = self.mix(x.flatten(2))                                         # (B, C, cells)
        x = self.channel_proj(x.permute(0, 2, 1)).permute(0, 2, 1)         # (B, out_channels, cells)
        return F.normalize(self.row_proj(x).flatten(1), p=2.0, dim=-1)


# ---------------------------------------------------------------------------------------- architectures
class NetVLADNet(nn.Module):
    def __init__(self, clusters: int, bias: bool) -> None:
        super().__init__()
        self.encoder = vgg16_conv5_3()
        self.pool = NetVLAD(clusters, 512, bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # noqa: D102
        return self.pool(self.encoder(x))


class GeoLocalizationNet(nn.Module):
    """CosPlace's and EigenPlaces' network: backbone, then L2Norm, GeM, Flatten, Linear, L2Norm."""

    def __init__(self, backbone: nn.Sequential, features: int, out_dim: int) -> None:
        super().__init__()
        self.backbone = backbone
        self.aggregation = nn.Sequential(L2Norm(), GeM(), Flatten(), nn.Linear(features, out_dim), L2Norm())

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # noqa: D102
        return self.aggregation(self.backbone(x))


class _ResNetHolder(nn.Module):
    """MixVPR's ``backbone``, which keeps the torchvision ResNet as ``model``."""

    def __init__(self, parts: list[tuple[str, nn.Module]]) -> None:
        super().__init__()
        self.model = NamedParts(parts)

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # noqa: D102
        return self.model(x)


class MixVPRNet(nn.Module):
    def __init__(self, backbone: str, n_layers: int, aggregator: MixVPR) -> None:
        super().__init__()
        self.backbone = _ResNetHolder(resnet_parts(backbone, n_layers))
        self.aggregator = aggregator

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # noqa: D102
        return self.aggregator(self.backbone(x))


class GeMNet(nn.Module):
    """A backbone tap + GeM + L2: a global descriptor from a network not trained for places."""

    def __init__(self, trunk: nn.Module) -> None:
        super().__init__()
        self.trunk = trunk
        self.pool = GeM()

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # noqa: D102
        return F.normalize(self.pool(self.trunk(x)).flatten(1), p=2.0, dim=1)


# ------------------------------------------------------------------------------------ reading checkpoints
class CheckpointError(ValueError):
    """A checkpoint that does not fit the architecture: the message lists what does not (one line)."""


def strip_prefixes(state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """``state`` without DataParallel's ``module.`` and Lightning's ``model.`` prefixes, where every
    architecture key carries one."""
    for prefix in ("module.", "model."):
        if state and all(k.startswith(prefix) for k in state):
            state = {k[len(prefix):]: v for k, v in state.items()}
    return state


def _count(state: dict[str, torch.Tensor], pattern: str) -> int:
    """How many distinct indices N the keys matching ``pattern`` (a regex with one group for N) have."""
    rx = re.compile(pattern)
    return len({m.group(1) for k in state if (m := rx.match(k))})


def _resnet_of(state: dict[str, torch.Tensor], prefix: str, sep: str, names: tuple[str, ...]) -> tuple[str, int]:
    """(resnet name, layers present) from the keys under ``prefix``: ``names`` are the four layers' key
    names (``layer1`` ... or ``4`` ... ``7``), ``sep`` what joins them to the block index."""
    n_layers = sum(1 for n in names if any(k.startswith(f"{prefix}{n}{sep}") for k in state))
    blocks = tuple(_count(state, rf"{re.escape(prefix + n + sep)}(\d+)\.") for n in names[:n_layers])
    bottleneck = any(k.startswith(f"{prefix}{names[0]}{sep}0.conv3.") for k in state)
    for name, (bn, full) in RESNETS.items():
        if bn == bottleneck and blocks == full[:n_layers]:
            return name, n_layers
    kind = "bottleneck" if bottleneck else "basic"
    raise CheckpointError(f"its ResNet backbone has {blocks} {kind} blocks per layer, none of {', '.join(RESNETS)}")


def _need(state: dict[str, torch.Tensor], *keys: str) -> None:
    missing = [k for k in keys if k not in state]
    if missing:
        raise CheckpointError(f"it lacks {', '.join(missing)}")


def make_netvlad(state: dict[str, torch.Tensor], size: tuple[int, int]) -> tuple[nn.Module, str]:
    _need(state, "pool.centroids", "pool.conv.weight")
    clusters = int(state["pool.centroids"].shape[0])
    return NetVLADNet(clusters, "pool.conv.bias" in state), f"VGG16 + NetVLAD, {clusters} clusters"


def make_geolocalization(state: dict[str, torch.Tensor], size: tuple[int, int]) -> tuple[nn.Module, str]:
    _need(state, "backbone.0.weight", "aggregation.3.weight", "aggregation.1.p")
    out_dim, features = (int(d) for d in state["aggregation.3.weight"].shape)
    if tuple(state["backbone.0.weight"].shape[-2:]) == (3, 3):      # VGG16's first conv
        return GeoLocalizationNet(vgg16_conv5_3(), 512, out_dim), f"VGG16, {out_dim} dims"
    name, n_layers = _resnet_of(state, "backbone.", ".", ("4", "5", "6", "7"))
    parts = [m for _, m in resnet_parts(name, n_layers)]
    return (GeoLocalizationNet(nn.Sequential(*parts), resnet_channels(name, n_layers), out_dim),
            f"{name} to layer{n_layers}, {out_dim} dims")


def make_mixvpr(state: dict[str, torch.Tensor], size: tuple[int, int]) -> tuple[nn.Module, str]:
    _need(state, "aggregator.mix.0.mix.0.weight", "aggregator.mix.0.mix.1.weight", "aggregator.channel_proj.weight",
          "aggregator.row_proj.weight", "backbone.model.conv1.weight")
    name, n_layers = _resnet_of(state, "backbone.model.", ".", ("layer1", "layer2", "layer3", "layer4"))
    cells = int(state["aggregator.mix.0.mix.0.weight"].shape[0])
    ratio = int(state["aggregator.mix.0.mix.1.weight"].shape[0]) / cells
    depth = _count(state, r"aggregator\.mix\.(\d+)\.")
    out_channels, in_channels = (int(d) for d in state["aggregator.channel_proj.weight"].shape)
    out_rows = int(state["aggregator.row_proj.weight"].shape[0])
    stride = 2 ** (n_layers + 1)
    grid = (-(-size[0] // stride), -(-size[1] // stride))
    if grid[0] * grid[1] != cells:
        raise CheckpointError(f"its mixers take {cells} feature-map cells, but a {size[0]}x{size[1]} input "
                              f"gives {grid[0]}x{grid[1]} = {grid[0] * grid[1]} after layer{n_layers}: give "
                              f"--width/--height that make {cells} cells (stride {stride}; 320x320 for 400)")
    return (MixVPRNet(name, n_layers, MixVPR(in_channels, cells, out_channels, depth, ratio, out_rows)),
            f"{name} to layer{n_layers} + MixVPR, {depth} mixers, {out_channels * out_rows} dims")


@dataclass(frozen=True)
class Architecture:
    name: str
    describe: str
    make: Callable[[dict, tuple[int, int]], tuple[nn.Module, str]]


ARCHITECTURES = {
    "netvlad": Architecture("netvlad", "VGG16 + NetVLAD (Nanne/pytorch-NetVlad's layout)", make_netvlad),
    "cosplace": Architecture("cosplace", "ResNet or VGG16 + GeM + linear (gmberton/CosPlace's layout)",
                             make_geolocalization),
    "eigenplaces": Architecture("eigenplaces", "as cosplace (gmberton/EigenPlaces's layout)", make_geolocalization),
    "mixvpr": Architecture("mixvpr", "ResNet to layer3 + MixVPR (amaralibey/MixVPR's layout)", make_mixvpr),
}


def check_fits(model: nn.Module, state: dict[str, torch.Tensor], architecture: str, source: str) -> None:
    """CheckpointError naming ``source`` and listing the architecture's keys the checkpoint lacks or holds
    in another shape (and keys under the architecture's own prefixes it does not know), one line."""
    own = model.state_dict()
    prefixes = {k.split(".")[0] + "." for k in own}
    missing = [k for k in own if k not in state]
    shaped = [f"{k}: {tuple(state[k].shape)} given, {tuple(own[k].shape)} expected" for k in own
              if k in state and tuple(state[k].shape) != tuple(own[k].shape)]
    unknown = [k for k in state if k not in own and any(k.startswith(p) for p in prefixes)
               and not k.endswith("num_batches_tracked")]
    if missing or shaped or unknown:
        said = [f"{len(missing)} key(s) missing ({', '.join(missing[:4])}{', ...' if len(missing) > 4 else ''})"
                if missing else "",
                f"{len(shaped)} of another shape ({'; '.join(shaped[:3])}{'; ...' if len(shaped) > 3 else ''})"
                if shaped else "",
                f"{len(unknown)} unknown ({', '.join(unknown[:4])}{', ...' if len(unknown) > 4 else ''})"
                if unknown else ""]
        raise CheckpointError(f"{source}: does not fit {architecture}: " + "; ".join(s for s in said if s))


def build_place_net(architecture: str, state: dict[str, torch.Tensor], size: tuple[int, int],
                    source: str) -> tuple[nn.Module, str]:
    """The ``architecture`` network sized from ``state``'s shapes, its weights loaded, in eval mode, and
    a line saying what it is. CheckpointError (one line, naming ``source``) when the checkpoint does not fit."""
    state = strip_prefixes(state)
    try:
        model, what = ARCHITECTURES[architecture].make(state, size)
    except CheckpointError as e:
        raise CheckpointError(f"{source}: not a {architecture} checkpoint: {e}") from None
    check_fits(model, state, architecture, source)
    own = model.state_dict()
    model.load_state_dict({k: state[k] for k in own}, strict=True)
    return model.eval(), what
