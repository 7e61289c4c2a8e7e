"""build-map --ray: the per-frame work on a Ray cluster (a local one here) writes the plain build's map; bad
addresses, a missing Ray and a worker that dies are one line, exit 2, nothing written."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from helpers import invoke
from vpr_edge.map import load_map

ray = pytest.importorskip("ray")


@pytest.fixture(scope="module", autouse=True)
def local_cluster():
    yield
    if ray.is_initialized():
        ray.shutdown()


def same_stored(a: Path, b: Path) -> None:
    x, y = load_map(a).stored.to_arrays(), load_map(b).stored.to_arrays()
    assert set(x) == set(y) and all(np.array_equal(x[k], y[k]) for k in x)


@pytest.mark.slow
def test_ray_build_is_the_plain_build(tmp_path: Path, small_refs: Path, small_queries: Path) -> None:
    plain, on_ray = tmp_path / "plain.npz", tmp_path / "ray.npz"
    # a fit sample of a few references: the rest are described and encoded on the workers
    fit = ("--components", "2", "--max-descriptors", "60", "--pca-dim", "16", "--batch-size", "4")
    assert invoke("build-map", small_refs, "-o", plain, *fit)[0] == 0
    code, _, err = invoke("build-map", small_refs, "-o", on_ray, *fit, "--ray", "local")
    assert code == 0, err
    same_stored(plain, on_ray)
    assert load_map(plain).encoder.same_as(load_map(on_ray).encoder)
    answers = [invoke("localize", "-m", m, "-s", small_queries)[1] for m in (plain, on_ray)]
    assert answers[0] == answers[1] and answers[0].count("\n") == 25


@pytest.mark.slow
def test_a_worker_that_dies_writes_nothing(tmp_path: Path, small_refs: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from vpr_edge.map import fleet

    out = tmp_path / "m.npz"
    assert invoke("build-map", small_refs, "-o", out, "--components", "2", "--save-codebook", tmp_path / "cb.npz")[0] == 0
    before = out.read_bytes()

    def dies(*args, **kwargs):
        os._exit(1)

    monkeypatch.setattr(fleet, "_encode_shard", dies)
    code, _, err = invoke("build-map", small_refs, "-o", out, "--codebook", tmp_path / "cb.npz", "--ray", "local")
    lines = [ln for ln in err.splitlines() if ln.startswith("vpr-edge: error:")]
    assert code == 2 and len(lines) == 1 and "--ray local" in lines[0], err
    assert out.read_bytes() == before


def test_ray_addresses_and_inputs_refused_before_the_work(tmp_path: Path, small_refs: Path) -> None:
    out = tmp_path / "m.npz"
    vectors = tmp_path / "v.npy"
    np.save(vectors, np.ones((3, 8), np.float32))
    with socketserver_port() as port:
        closed = f"127.0.0.1:{port}"
    for args, needle in (((small_refs, "--ray", closed), "no Ray cluster answers"),
                         ((small_refs, "--ray", "nowhere"), "HOST:PORT"),
                         ((vectors, "--ray", "local"), "--ray local"),
                         ((small_refs, "--encoding", "bow", "--tfidf", "--ray", "local"), "--tfidf")):
        code, _, err = invoke("build-map", *args, "-o", out)
        assert code == 2 and err.count("\n") == 1 and needle in err, (args, err)
    assert not out.exists()


def test_ray_missing_is_one_line(tmp_path: Path, small_refs: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import sys

    monkeypatch.setitem(sys.modules, "ray", None)   # import raises ImportError, as if not installed
    code, _, err = invoke("build-map", small_refs, "-o", tmp_path / "m.npz", "--ray", "local")
    assert code == 2 and err.count("\n") == 1 and "vpr-edge[ray]" in err


class socketserver_port:
    """A TCP port that was free a moment ago (bound, then closed)."""

    def __enter__(self) -> int:
        import socket

        self.s = socket.socket()
        self.s.bind(("127.0.0.1", 0))
        return self.s.getsockname()[1]

    def __exit__(self, *exc) -> None:
        self.s.close()
