"""build-map as a library: the plan checks without doing the work (no positions read, no model picked by
the camera), its errors name the options as the library does and the CLI says them as its flags; no library
message names a flag."""
from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

from vpr_edge.cli.common import flag
from vpr_edge.errors import InputError, Message, VprError, input_names
from vpr_edge.map.gather import gather
from vpr_edge.map.options import BuildOptions
from vpr_edge.map.plan import plan_map
from vpr_edge.positions import PositionSource

PACKAGE = Path(__file__).resolve().parent.parent / "vpr_edge"
LIBRARY = sorted(p for p in PACKAGE.rglob("*.py") if "cli" not in p.relative_to(PACKAGE).parts)
# strings outside cli/ that may name a flag, each for its reason: (file, the string's start)
ALLOWED = [
    ("viewer.py", "--port"),                 # the Rerun Viewer's own command line (argv of a subprocess)
    ("viewer.py", "--hide-welcome-screen"),  # ditto
    ("viewer.py", "--expect-data-soon"),     # ditto
    ("registry.py", "one linear SVM"),       # svm's summary for --list-params: which build-map option makes it
    ("registry.py", "an ONNX model (--model"),   # cnn's summary for build-map --help
    # bench's report (not an error): the localize command line it recommends, and bench's own --fps
    ("sweep.py", "; --precision auto here: "),
    ("sweep.py", "; --fps F picks the setting"),
    ("sweep.py", ": localize --threads "),
    ("sweep.py", " --precision "),
]


def test_the_plan_reads_no_positions_and_picks_no_model(small_refs: Path, tmp_path: Path) -> None:
    bad = tmp_path / "pos.csv"
    bad.write_text("x,y\n" + "0,north\n" * 24)
    plan = plan_map(small_refs, tmp_path / "m.npz", BuildOptions(positions=str(bad)))
    assert plan.drives[0].positions == PositionSource("csv", str(bad)) and plan.drives[0].kind == "images"
    assert plan.by_camera and len(plan.drives[0].files) == 24
    with pytest.raises(VprError, match="line 2: y 'north' is not a number"):   # read by the work, not the plan
        gather(plan)
    good = tmp_path / "good.csv"
    good.write_text("x,y\n" + "".join(f"0,{i}\n" for i in range(24)))
    with gather(plan_map(small_refs, tmp_path / "m.npz", BuildOptions(positions=str(good)))) as inputs:
        assert inputs.model_choice == "camera 160x120: efficientnet_lite0_stage5_160x120.onnx"
        assert inputs.positions.coords[:, 1].tolist() == list(range(24)) and len(inputs.files) == 24


def test_errors_name_the_options_as_the_library_and_the_cli_does(small_refs: Path, tmp_path: Path) -> None:
    with pytest.raises(InputError) as wrong:
        plan_map(small_refs, tmp_path / "m.npz", BuildOptions(features="hog", resize="pad"))
    assert wrong.value.inputs == ("resize",)
    assert str(wrong.value) == "resize applies to the cnn front end, not hog"
    assert wrong.value.line(flag) == "--resize applies to the cnn front end, not hog"
    with input_names(flag):
        assert str(wrong.value) == "--resize applies to the cnn front end, not hog"
    with pytest.raises(InputError) as wrong:
        plan_map(small_refs, tmp_path / "m.npz", BuildOptions(codebook=tmp_path / "cb.npz", components=8, whiten=True))
    assert wrong.value.inputs == ("components", "whiten", "no_whiten", "codebook")
    assert wrong.value.line(flag) == (f"--components, --whiten/--no-whiten: options for fitting a codebook, but "
                                      f"--codebook {tmp_path / 'cb.npz'} is given")



def test_errors_outside_the_map_name_the_library_inputs_and_the_cli_flags() -> None:
    """The same error, as a library caller reads it and as the CLI says it (exit 2, text as before)."""
    from vpr_edge.evaluation.run import Source
    from vpr_edge.matchers import get_matcher
    from vpr_edge.matchers.base import check_target_precision

    with pytest.raises(InputError) as wrong:
        Source(pixels=True, queries="q").check()
    assert str(wrong.value) == "pixels needs refs (the reference folder)"
    assert wrong.value.line(flag) == "--features pixels needs --refs (the reference folder)"
    with pytest.raises(InputError) as wrong:
        check_target_precision(1.5)
    assert wrong.value.inputs == ("target_precision",)
    assert str(wrong.value).startswith("target_precision 1.5: ")
    assert wrong.value.line(flag).startswith("--target-precision 1.5: the target precision must lie between 0 and 1")
    with pytest.raises(InputError) as wrong:   # a live line: a target precision sets no line of `stream-rules`
        get_matcher("stream-rules").lost_line(None, 0.99, live=True)
    assert wrong.value.inputs == ("target_precision", "min_confidence", "calibration")
    assert wrong.value.line(flag).startswith("--target-precision 0.99: mode stream-rules's score is not the probability")
    assert get_matcher("stream-rules").lost_line(None, 0.99) == get_matcher("stream-rules").min_confidence   # evaluate's
    assert get_matcher("stream").lost_line(None, 0.99, live=True) == 0.99
    # a labelled drive's line sets any mode's: the score its answers reached the precision at
    assert get_matcher("stream-rules").lost_line(None, 0.99, live=True, line=lambda p: 1.2 + p) == 2.19
    assert get_matcher("stream").lost_line(None, 0.9, live=True, line=lambda p: 0.5) == 0.5
    assert get_matcher("stream-rules").lost_line(1.3, 0.99, live=True, line=lambda p: 0.5) == 1.3   # given wins
    assert get_matcher("stream-rules").lost_line(None, 0.99, line=lambda p: float("inf")) == float("inf")   # all lost
    with pytest.raises(ValueError) as refused:   # a ValueError still, as callers of parse_params catch
        get_matcher("seqslam").parse_params(["ds=x"])
    assert str(refused.value) == "params 'ds=x': 'x' is not an int"
    with input_names(flag):
        assert str(refused.value) == "--param 'ds=x': 'x' is not an int"

def test_a_message_takes_values_as_they_are() -> None:
    said = Message("{at}: {opt.positions_topic} {topic} ({n:.1f} s)", at="a{b}/c", topic="/gps {x}", n=2.25)
    assert str(said) == "a{b}/c: positions_topic /gps {x} (2.2 s)" and said.inputs == ("positions_topic",)
    joined = Message.join([Message("{opt.ray} {r}", r="local"), "plain {"])
    assert joined.line(flag) == "--ray local, plain {" and joined.inputs == ("ray",)


def test_no_library_message_names_an_option_flag() -> None:
    """The library names its inputs ``{opt.NAME}``; a flag (``--positions``) in any string of its code
    (docstrings aside) is the CLI's word in the library, outside cli/ and the ``ALLOWED`` strings."""
    found = []
    for path in LIBRARY:
        tree = ast.parse(path.read_text())
        docs = {id(n.value) for n in ast.walk(tree) if isinstance(n, ast.Expr) and isinstance(n.value, ast.Constant)}
        found += [f"{path.name}:{c.lineno}: {c.value}" for c in ast.walk(tree) if isinstance(c, ast.Constant)
                  and isinstance(c.value, str) and id(c) not in docs and re.search(r"(^|[\s(])--[a-z]", c.value)
                  and not any(path.name == name and c.value.startswith(start) for name, start in ALLOWED)]
    assert not found, found
