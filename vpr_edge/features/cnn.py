"""Local deep features from an ONNX layer tap: preprocessing, batched inference, (N, K) descriptor sets."""
from __future__ import annotations

import copy
import json
import math
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vpr_edge.errors import InputError, Message, VprError, warn
from vpr_edge.features.conventions import GivenConventions, InputConventions
from vpr_edge.features.resize import RESIZE, content_cells, fit_to_input
from vpr_edge.files.npz import newer_schema
from vpr_edge.files.readers import file_sha256
from vpr_edge.resources import SMALL_MODEL_FILE, bundled_model

MODEL_SCHEMA = 1
_REQUIRED = ("backbone", "tap", "input_width", "input_height", "mean", "std", "channels", "grid_width",
             "grid_height", "weights_sha256")


def _checked_info(path: Path, raw: str) -> dict:
    """The model's ``vpr_edge`` metadata, every field the runtime uses checked (VprError naming the field)."""
    try:
        info = json.loads(raw)
    except json.JSONDecodeError as e:
        raise VprError(f"{path}: model metadata is not valid JSON ({e})") from None
    if not isinstance(info, dict):
        raise VprError(f"{path}: model metadata is a JSON {type(info).__name__}, expected an object")
    newer = newer_schema(path, "model metadata", info.get("schema"), (MODEL_SCHEMA,))
    if newer:
        raise VprError(newer)
    missing = [k for k in _REQUIRED if k not in info]
    if info.get("schema") != MODEL_SCHEMA or missing:
        raise VprError(f"{path}: model metadata schema {info.get('schema')} unsupported "
                       f"(expected {MODEL_SCHEMA}{', missing ' + ', '.join(missing) if missing else ''})")

    def positive_int(key: str) -> bool:
        return isinstance(info[key], int) and not isinstance(info[key], bool) and 0 < info[key] <= 1 << 16

    for key in ("input_width", "input_height", "channels", "grid_width", "grid_height"):
        if not positive_int(key):
            raise VprError(f"{path}: model metadata field {key!r} must be a positive integer, got {info[key]!r}")
    for key in ("mean", "std"):
        v = info[key]
        if not (isinstance(v, list) and len(v) == 3 and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                            and math.isfinite(x) for x in v)):
            raise VprError(f"{path}: model metadata field {key!r} must be three finite numbers, got {v!r}")
    if min(info["std"]) <= 0:
        raise VprError(f"{path}: model metadata field 'std' must be positive, got {info['std']!r}")
    for key in ("backbone", "tap", "weights_sha256"):
        if not isinstance(info[key], str):
            raise VprError(f"{path}: model metadata field {key!r} must be text, got {info[key]!r}")
    if "resize" in info and not isinstance(info["resize"], str):
        raise VprError(f"{path}: model metadata field 'resize' must be text, got {info['resize']!r}")
    return info


def default_model_path() -> Path:
    """The default model: ``$VPR_EDGE_MODEL`` if set, else the bundled one (``resources.bundled_model``)."""
    return resolve_model(None)


MODEL_ENV = "VPR_EDGE_MODEL"   # the environment variable that names the model to run


def model_from_env() -> Path | None:
    """The model ``$VPR_EDGE_MODEL`` names (None: unset). Raises VprError when it names no file, rather than
    falling through to another model. The one place the variable is read."""
    env = os.environ.get(MODEL_ENV)
    if not env:
        return None
    if not Path(env).is_file():
        raise VprError(f"{env}: model file not found (named by the {MODEL_ENV} environment variable)")
    return Path(env)


def resolve_model(given: Path | None, recorded: Path | None = None) -> Path:
    """The model to run, by precedence: ``given`` (``--model``), then ``$VPR_EDGE_MODEL``, then ``recorded``
    (the file a map was built with) if it still exists, then the bundled model. Raises VprError when
    ``$VPR_EDGE_MODEL`` is set but names no file, rather than falling through to another model."""
    if given is not None:
        return Path(given)
    env = model_from_env()
    if env is not None:
        return env
    if recorded is not None and recorded.name and recorded.is_file():
        return recorded
    return bundled_model()



class FeatureExtractor:
    """An ONNX feature tap (exported by ``vpr_edge_export.onnx_export``) and its preprocessing.

    ``info`` is the model's metadata (backbone, tap, input size, mean/std, channels, weights hash);
    ``fingerprint`` is the SHA-256 of the ONNX file, which maps record to refuse a different model.
    It is the ``cnn`` front end (``vpr_edge.features.FrontEnd``). ``resize`` is how a frame is brought to
    the model's input (``RESIZE``; default: the model's metadata ``resize`` if any, else ``stretch``); a map
    records it, and its queries are resized the same way.
    """

    name = "cnn"
    binary = False
    needs_fit = False

    def __init__(self, model_path: str | os.PathLike[str], threads: int = 0, resize: str | None = None,
                 conventions: InputConventions | GivenConventions | None = None) -> None:
        import onnxruntime as ort

        self.path = Path(model_path)
        if not self.path.is_file():
            raise InputError("{path}: model file not found (pass {opt.model} PATH)", path=self.path)
        ort.set_default_logger_severity(3)   # errors only: no warnings of its own on the tool's stderr
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = max(0, int(threads))
        opts.log_severity_level = 3
        # Idle ORT workers would otherwise spin and starve the NumPy encoding that follows each frame.
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
        try:
            self.session = ort.InferenceSession(str(self.path), opts, providers=["CPUExecutionProvider"])
        except Exception as e:  # onnxruntime raises several private exception types
            raise VprError(f"{self.path}: not a loadable ONNX model on onnxruntime's CPU provider "
                           f"({str(e).splitlines()[0][:120]})") from None
        inp, out = self.session.get_inputs()[0], self.session.get_outputs()[0]
        self._input = inp.name
        # a model exported with a fixed batch size runs that many images at a time (``feature_maps``)
        self._batch = inp.shape[0] if isinstance(inp.shape[0], int) and inp.shape[0] > 0 else None
        self.output = _output_kind(self.path, out.shape)
        raw = self.session.get_modelmeta().custom_metadata_map.get("vpr_edge")
        self.fingerprint = file_sha256(self.path)
        stated = conventions if isinstance(conventions, InputConventions) else None
        if raw is not None:
            if stated is not None or (isinstance(conventions, GivenConventions) and conventions.given):
                given = conventions.options() if isinstance(conventions, GivenConventions) else ["the map's"]
                raise InputError("{path}: the model records its input conventions in its vpr_edge metadata; "
                                 "drop {given}", path=self.path, given=Message.join(given))
            info = _checked_info(self.path, raw)
            self.conventions = InputConventions.from_record(info, str(self.path))
            self.stated = False
        else:
            if stated is None:
                stated = (conventions or GivenConventions()).resolve(inp.shape, str(self.path))
            self.conventions = stated
            self.stated = True      # recorded in the map: its queries are preprocessed the same way
            info = self._probed_info()
        self.info: dict = info
        c = self.conventions
        self.size = (c.width, c.height)
        self._mean = np.asarray(c.mean, np.float32)
        self._std = np.asarray(c.std, np.float32)
        self._planes = (2, 1, 0) if c.bgr else (0, 1, 2)    # the image's channel read into each model channel
        self.resize = str(resize or info.get("resize") or "stretch")
        # the numeric form run and why (``as_run``: map.front.map_front_end says why it chose it)
        self.form = "int8" if info.get("quantization") else "fp32"
        if self.resize not in RESIZE:
            raise VprError(f"{self.path}: unknown resize policy {self.resize!r}; choose from {', '.join(RESIZE)}")
        self._scale = (1.0 / (255.0 * self._std)).astype(np.float32)   # (x / 255 - mean) / std, per channel
        self._offset = (self._mean / self._std).astype(np.float32)
        # padding is the mean colour (a zero input), in the image's RGB order
        self._fill = np.clip(np.rint(self._mean[list(self._planes)] * 255.0), 0, 255).astype(np.uint8)

    def _probed_info(self) -> dict:
        """Metadata for a model exported elsewhere: what one run on a blank image shows of its output."""
        blank = np.zeros((1, 3, self.conventions.height, self.conventions.width), np.float32)
        try:
            shape = self.feature_maps(blank).shape
        except Exception as e:  # onnxruntime's own errors: an input that contradicts the model
            raise InputError("{path}: the model does not run on a {w}x{h} {layout} input ({why}); check "
                             "{opt.input_size} and {opt.layout}", path=self.path, w=self.conventions.width,
                             h=self.conventions.height, layout=self.conventions.layout,
                             why=str(e).splitlines()[0][:120]) from None
        grid = (1, 1) if self.output == "global" else (int(shape[3]), int(shape[2]))
        return {"schema": MODEL_SCHEMA, "backbone": self.path.stem, "tap": self.session.get_outputs()[0].name,
                "output": self.output, "channels": int(shape[1]), "grid_width": grid[0], "grid_height": grid[1],
                "weights_sha256": self.fingerprint} | self.conventions.describe()

    @property
    def colour(self) -> str | None:
        """The colour the model expects, in its channel order (RGB, or BGR): its metadata's ``color``, else
        the input conventions'; None when the metadata names no colour order (a model of grey frames)."""
        order = str(self.info.get("color", "BGR" if self.conventions.bgr else "RGB")).upper()
        return order if order in ("RGB", "BGR") else None

    def as_run(self, form: str) -> "FeatureExtractor":
        """This extractor (the same session) described as running in ``form``: its numeric form and why it
        was chosen (e.g. "int8: AVX512-VNNI"), what ``runs()`` reports."""
        chosen = copy.copy(self)
        chosen.form = form
        return chosen

    def runs(self) -> dict:
        """{"name": "cnn", "model": the file run, "form": its numeric form and why}."""
        return {"name": self.name, "model": self.path.name, "form": self.form}

    @property
    def source_fingerprint(self) -> str | None:
        """For an int8 model written by ``vpr_edge_export.quantize``, the SHA-256 of the fp32 model it was
        made from (its features approximate that model's, so a codebook fitted on them fits); else None."""
        return (self.info.get("quantization") or {}).get("source_sha256")

    @property
    def dim(self) -> int:
        """Channels K of the tap: the dimension of each local descriptor."""
        return int(self.info["channels"])

    @property
    def n_local(self) -> int:
        """N = grid width x grid height of the tap; 1 for a global model (its one descriptor an image)."""
        return 1 if self.output == "global" else int(self.info["grid_width"]) * int(self.info["grid_height"])

    @property
    def is_global(self) -> bool:
        """Whether the model outputs one global descriptor an image (B, D), encoded as it is (no codebook)."""
        return self.output == "global"

    def describe(self) -> dict:
        """The front-end record of a map (the model's identity is recorded beside it: ``identity``); with
        the input conventions when the user stated them (a model without vpr_edge metadata)."""
        params: dict = {"resize": self.resize}
        if self.stated:
            params["input"] = self.conventions.describe()
        return {"name": self.name, "params": params}

    def identity(self) -> dict:
        """The model a map was built with: its metadata, file name, absolute path and SHA-256."""
        return {"model": self.info, "model_file": self.path.name, "model_path": str(self.path.resolve()),
                "model_sha256": self.fingerprint}

    def fit(self, local: np.ndarray, seed: int = 0) -> "FeatureExtractor":
        """Nothing to fit: the model is trained."""
        return self

    def select(self, local: np.ndarray) -> np.ndarray:
        return local

    def local(self, images: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray | None]:
        """RGB uint8 images (H, W, 3) -> local descriptors (B, N, K) float32 in one model run, and under
        ``pad`` the mask (B, N) of the cells that see the image (the padding's descriptors, the same in every
        image, would otherwise weigh in every encoding); else no mask."""
        x = self.local_features(np.stack([self.preprocess(im) for im in images]))
        if self.resize != "pad" or self.is_global:
            return x, None
        grid = (int(self.info["grid_width"]), int(self.info["grid_height"]))
        return x, np.stack([content_cells(im.shape, self.size, grid) for im in images])

    def preprocess(self, rgb: np.ndarray) -> np.ndarray:
        """RGB uint8 (H, W, 3) -> normalised float32 (3, input_height, input_width)."""
        if 4 * rgb.shape[1] < self.size[0] or 4 * rgb.shape[0] < self.size[1]:
            warn(Message(f"{rgb.shape[1]}x{rgb.shape[0]} images are upsampled more than 4x per side to the model's "
                         f"{self.size[0]}x{self.size[1]} input ({{name}}); a model with a smaller input suits them"
                         + (" (bundled: {opt.model} {small})" if self.size[0] > 160 else ""),
                         name=self.path.name, small=bundled_model(SMALL_MODEL_FILE)))
        x = fit_to_input(rgb, self.size, self.resize, self._fill)
        out = np.empty((3,) + x.shape[:2], np.float32)
        for c, src in enumerate(self._planes):  # one plane at a time, in place: 4x faster than float temporaries
            np.multiply(x[:, :, src], self._scale[c], out=out[c], casting="unsafe")
            out[c] -= self._offset[c]
        return out

    def feature_maps(self, batch: np.ndarray) -> np.ndarray:
        """Preprocessed batch (B, 3, H, W) float32 -> the model's output: the tap (B, K, h, w) float32, or
        a global model's descriptors (B, D). NHWC models get the batch transposed; a model of fixed batch
        size runs that many images a call (the last call padded with blank images)."""
        x = batch.astype(np.float32, copy=False)
        if self.conventions.layout == "nhwc":
            x = np.ascontiguousarray(x.transpose(0, 2, 3, 1))
        if self._batch is None or len(x) == self._batch:
            return self.session.run(None, {self._input: x})[0]
        parts = []
        for i in range(0, len(x), self._batch):
            part = x[i:i + self._batch]
            short = self._batch - len(part)
            if short:
                part = np.concatenate([part, np.zeros((short,) + part.shape[1:], np.float32)])
            parts.append(self.session.run(None, {self._input: part})[0][:self._batch - short])
        return np.concatenate(parts)

    def local_features(self, batch: np.ndarray) -> np.ndarray:
        """Preprocessed batch (B, 3, H, W) -> local descriptors (B, N = h*w, K) float32; a global model's
        descriptor as its one local descriptor (B, 1, D)."""
        fmap = self.feature_maps(batch)
        if self.is_global:
            return np.ascontiguousarray(fmap, np.float32)[:, None, :]
        b, k = fmap.shape[:2]
        return np.ascontiguousarray(fmap.reshape(b, k, -1).transpose(0, 2, 1))


def _output_kind(path: Path, shape: list) -> str:
    """"global" for an output (batch, D), "local" for a feature map (batch, K, h, w); VprError else."""
    if len(shape) == 2:
        return "global"
    if len(shape) == 4:
        return "local"
    raise VprError(f"{path}: model output has rank {len(shape)} ({shape}); expected a global descriptor "
                   f"(batch, D) or a feature map (batch, K, h, w)")
