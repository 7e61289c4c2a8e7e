"""How an ONNX model takes its image: input size, channel order, normalisation and layout.

A model exported by ``vpr_edge_export`` records them in its ``vpr_edge`` metadata; a model exported elsewhere
(a NetVLAD, CosPlace or MixVPR network's own export) does not, and its user states them (build-map's
``--input-size``, ``--mean``, ``--std``, ``--bgr``, ``--layout``); the map records them so that its queries
are preprocessed the same way. Pixels are scaled to [0, 1], then ``(x - mean) / std`` per channel, the
channels in the order the model takes them (RGB, or BGR with ``bgr``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from vpr_edge.errors import InputError, Message, VprError

LAYOUTS = {"nchw": "batch, channels, height, width (PyTorch's)", "nhwc": "batch, height, width, channels (TF's)"}
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
NORMALISATIONS = {"imagenet": (IMAGENET_MEAN, IMAGENET_STD)}   # names mean / std also take
OPTIONS = Message("{opt.input_size} WxH, {opt.mean} and {opt.std}; {opt.bgr} and {opt.layout} nhwc where the "
                  "model takes those")


@dataclass(frozen=True)
class InputConventions:
    """A model's input: ``width`` x ``height`` pixels, ``mean`` / ``std`` (3,) on the [0, 1] scale in the
    model's channel order, ``bgr`` (channels B, G, R), ``layout`` (``LAYOUTS``)."""

    width: int
    height: int
    mean: tuple[float, float, float]
    std: tuple[float, float, float]
    bgr: bool = False
    layout: str = "nchw"

    def __post_init__(self) -> None:
        for key in ("width", "height"):
            v = getattr(self, key)
            if not (isinstance(v, int) and not isinstance(v, bool) and 0 < v <= 1 << 16):
                raise VprError(f"input {key} must be a positive integer, got {v!r}")
        for key in ("mean", "std"):
            v = getattr(self, key)
            if not (isinstance(v, tuple) and len(v) == 3 and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                               and math.isfinite(x) for x in v)):
                raise InputError(f"{{opt.{key}}} must be three finite numbers (one per channel), got {{v!r}}", v=v)
        if min(self.std) <= 0:
            raise InputError("{opt.std} must be positive, got {std!r}", std=self.std)
        if self.layout not in LAYOUTS:
            raise InputError("{opt.layout} {layout!r}: choose from {names}", layout=self.layout, names=", ".join(LAYOUTS))

    def describe(self) -> dict:
        """The JSON a map records (``from_record`` reads it back)."""
        return {"input_width": self.width, "input_height": self.height, "mean": list(self.mean),
                "std": list(self.std), "bgr": self.bgr, "layout": self.layout}

    @classmethod
    def from_record(cls, record: dict, source: str = "") -> "InputConventions":
        """The conventions ``describe()`` wrote (a map's, or a model's metadata, which has no bgr/layout when
        the model takes RGB NCHW, and may say ``color``); VprError naming ``source`` when they do not parse."""
        try:
            bgr = bool(record.get("bgr", False)) or str(record.get("color", "RGB")).upper() == "BGR"
            return cls(int(record["input_width"]), int(record["input_height"]), tuple(record["mean"]),
                       tuple(record["std"]), bgr, str(record.get("layout", "nchw")))
        except (KeyError, TypeError, ValueError) as e:
            raise VprError(f"{source + ': ' if source else ''}input conventions not understood ({e})") from None


def parse_size(text: str) -> tuple[int, int]:
    """``"WxH"`` -> (width, height); InputError naming ``input_size`` otherwise."""
    parts = text.lower().split("x")
    if len(parts) != 2 or not all(p.strip().isdigit() and int(p) > 0 for p in parts):
        raise InputError("{opt.input_size} {text!r}: expected WIDTHxHEIGHT in pixels, e.g. 320x240", text=text)
    return int(parts[0]), int(parts[1])


def parse_triple(text: str, option: str) -> tuple[float, float, float]:
    """``"a,b,c"`` or a name of ``NORMALISATIONS`` -> three numbers; InputError naming ``option`` (``mean`` or
    ``std``) otherwise."""
    name = text.strip().lower()
    if name in NORMALISATIONS:
        return NORMALISATIONS[name][0 if option == "mean" else 1]
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise InputError(f"{{opt.{option}}} {{text!r}}: expected three numbers, one per channel on the [0, 1] scale "
                         "(e.g. 0.485,0.456,0.406), or {names}", text=text, names=", ".join(NORMALISATIONS))
    return values  # type: ignore[return-value]


@dataclass(frozen=True)
class GivenConventions:
    """What the user stated on the command line (None: not stated); ``resolve`` completes it from the model's
    input shape, where that is fixed."""

    size: str | None = None
    mean: str | None = None
    std: str | None = None
    bgr: bool = False
    layout: str | None = None

    @property
    def given(self) -> bool:
        return any(v not in (None, False) for v in (self.size, self.mean, self.std, self.bgr, self.layout))

    def options(self) -> list[Message]:
        """The options stated, each ``{opt.NAME}`` (for messages)."""
        return [Message(f"{{opt.{k}}}") for k, v in (("input_size", self.size), ("mean", self.mean),
                                                     ("std", self.std), ("bgr", self.bgr or None),
                                                     ("layout", self.layout)) if v is not None]

    def resolve(self, input_shape: list, source: str) -> InputConventions:
        """The conventions, checked against the model's input shape (B, 3, H, W) / (B, H, W, 3), whose
        fixed sizes fill in an unstated ``input_size``; InputError naming ``source`` and the options missing
        or contradicting the model."""
        if self.mean is None or self.std is None:
            missing = [Message(f"{{opt.{k}}}") for k, v in (("mean", self.mean), ("std", self.std)) if v is None]
            raise InputError("{source}: the model has no vpr_edge metadata and {missing} {verb} not given: state its "
                             "input conventions ({options}), or export it with vpr_edge_export", source=source,
                             missing=Message.join(missing, " and "), verb="is" if len(missing) == 1 else "are",
                             options=OPTIONS)
        shape = list(input_shape)
        if len(shape) != 4:
            raise VprError(f"{source}: model input has rank {len(shape)} ({shape}); an image input is "
                           f"(batch, 3, H, W) or (batch, H, W, 3)")
        layout = self.layout or _layout_of(shape)
        channels, h, w = (shape[1], shape[2], shape[3]) if layout == "nchw" else (shape[3], shape[1], shape[2])
        if isinstance(channels, int) and channels != 3:
            raise InputError("{source}: {opt.layout} {layout} reads the model's input {shape} as {channels} channels, "
                             "not 3 (try {opt.layout} {other})", source=source, layout=layout, shape=shape,
                             channels=channels, other="nhwc" if layout == "nchw" else "nchw")
        fixed = (w, h) if isinstance(w, int) and isinstance(h, int) else None
        if self.size is None and fixed is None:
            raise InputError("{source}: the model's input size is not fixed ({shape}): give {opt.input_size} WxH",
                             source=source, shape=shape)
        size = parse_size(self.size) if self.size is not None else fixed
        if fixed is not None and size != fixed:
            raise InputError("{source}: {opt.input_size} {w}x{h} contradicts the model's fixed input {fw}x{fh} ({shape})",
                             source=source, w=size[0], h=size[1], fw=fixed[0], fh=fixed[1], shape=shape)
        return InputConventions(size[0], size[1], parse_triple(self.mean, "mean"), parse_triple(self.std, "std"),
                                self.bgr, layout)


def _layout_of(shape: list) -> str:
    """nchw unless the input's only dimension of 3 is its last."""
    if shape[1] == 3 or shape[3] != 3:
        return "nchw"
    return "nhwc"
