"""The build's first piece of work (``gather``): a plan's drives taken in (each bag's images extracted, each
descriptor file and each drive's positions read, a folder's frame times where a GPX track needs them) and the
bundled model picked by the camera where the plan left it to the first frame. ``map.make`` then builds."""
from __future__ import annotations

import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vpr_edge.features import FrontEnd, make_front_end
from vpr_edge.features.choice import model_for_frame
from vpr_edge.frames.bags import extract_images
from vpr_edge.frames.descriptor_files import read_descriptors
from vpr_edge.frames.images import check_frame_sizes, load_image, read_stamps
from vpr_edge.map.drives import Drives, spans_of
from vpr_edge.map.options import BuildOptions
from vpr_edge.map.plan import DrivePlan, MapPlan, resized_to
from vpr_edge.positions import Positions, read_positions


@dataclass
class DriveInputs:
    """One drive taken in: its ``name``, ``source``, image ``files`` (a bag's once extracted), their names
    where not the files' (a bag's BAG#N, a descriptor file's rows), its positions, its frames' times (R,)
    seconds (None: not known) and, for a descriptor file, its (R, D) vectors (memory-mapped)."""

    name: str
    source: Path
    files: list[Path] = field(default_factory=list)
    names: list[str] | None = None
    positions: Positions | None = None
    stamps: np.ndarray | None = None
    descriptors: np.ndarray | None = None

    @property
    def count(self) -> int:
        return len(self.descriptors) if self.descriptors is not None else len(self.files)

    def place_names(self) -> list[str]:
        return list(self.names) if self.names is not None else [f.name for f in self.files]


@dataclass
class MapInputs:
    """A plan's drives taken in, the ``front`` end that describes them (``model_choice``: why this bundled
    model, when the camera chose it) and the ``scratch`` folder bags were extracted into (removed by
    ``close``, or on leaving a ``with`` block)."""

    plan: MapPlan
    drives: list[DriveInputs]
    front: FrontEnd
    model_choice: str | None = None
    scratch: tempfile.TemporaryDirectory | None = None

    @property
    def files(self) -> list[Path]:
        """Every drive's image files, drive after drive."""
        return [f for d in self.drives for f in d.files]

    @property
    def positions(self) -> Positions | None:
        """Every drive's positions, drive after drive (None: the drives have none)."""
        if self.drives[0].positions is None:
            return None
        out = self.drives[0].positions
        for d in self.drives[1:]:
            out = out.concat(d.positions)
        return out

    def drive_list(self) -> Drives:
        return Drives.of([d.name for d in self.drives], [d.count for d in self.drives],
                         [str(d.source) for d in self.drives], [spans_of(d.stamps) for d in self.drives])

    def close(self) -> None:
        if self.scratch is not None:
            self.scratch.cleanup()

    def __enter__(self) -> "MapInputs":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _taken_in(d: DrivePlan, folder: Path | None, o: BuildOptions) -> DriveInputs:
    """A drive's frames and positions: a descriptor file's vectors, or a bag's images decoded into
    ``folder``; a folder's images as listed, with their times where a GPX track needs them."""
    out = DriveInputs(d.name, d.source, list(d.files))
    if d.kind == "descriptors":
        out.descriptors, out.names = read_descriptors(d.source)
    elif d.kind == "bag":
        folder.mkdir()
        out.files, out.names, out.stamps = extract_images(d.source, o.topic, folder)
    elif d.timestamps is not None:
        out.stamps = np.asarray(read_stamps(d.timestamps, [f.name for f in out.files]))
    if d.positions is not None:
        out.positions = read_positions(d.positions, out.place_names(), out.files, out.stamps)
    return out


def gather(plan: MapPlan) -> MapInputs:
    """The work's first step: every drive taken in (``_taken_in``; a bag's frames checked to be of one size,
    as the plan checks a folder's), their positions checked to be in one frame (the appended map's, else the
    first drive's), and the bundled model picked by the camera where the plan leaves it to the first frame
    (``features.choice``)."""
    bags = any(d.kind == "bag" for d in plan.drives)
    inputs = MapInputs(plan, [], plan.front, scratch=tempfile.TemporaryDirectory(prefix="vpr-edge-bag-") if bags
                       else None)
    try:
        for k, d in enumerate(plan.drives):
            folder = Path(inputs.scratch.name) / str(k) if d.kind == "bag" else None
            inputs.drives.append(_taken_in(d, folder, plan.options))
            if d.kind == "bag":   # (a folder's frame sizes are checked by the plan)
                taken = inputs.drives[-1]
                check_frame_sizes(d.source, taken.files, plan.options.strict, taken.names, resized_to(plan.front))
        first = plan.base.positions if plan.base is not None else \
            next((d.positions for d in inputs.drives if d.positions is not None), None)
        for d in inputs.drives:
            if first is not None and d.positions is not None:
                first.check_frame(d.positions, str(d.source))
        if plan.by_camera:   # a folder's first image, else the first drive's first frame
            shown = next((d.files[0] for p, d in zip(plan.drives, inputs.drives) if p.files), inputs.files[0])
            height, width = load_image(shown).shape[:2]
            model = model_for_frame(width, height)
            inputs.model_choice = f"camera {width}x{height}: {model.name}"
            if getattr(plan.front, "path", None) != model:
                inputs.front = make_front_end("cnn", model, plan.ort_threads, spec=plan.front_spec)
    except BaseException:
        inputs.close()
        raise
    return inputs
