"""A fleet's build on a Ray cluster (``build-map --ray ADDRESS``): the per-frame work (decode, front end,
encoding) of every reference outside the codebook's fit sample runs as Ray tasks, a shard of whole batches
each, on the workers; the fit sample, the codebook fit and the writing stay in the building process.

Workers rebuild the front end and the encoder from the records a map file holds (``FrontEnd.describe``, the
model file, ``Encoder.to_arrays``), so they need the package installed and the frames and the model at the same
paths (shared storage); the batches are the plain build's, so the encodings are the same. Ray is the ``ray``
extra, imported only here (docs/usage.md, "Building on a cluster").
"""
from __future__ import annotations

import socket
from collections.abc import Iterator, Sequence
from pathlib import Path
from urllib.parse import urlparse

import numpy as np

from vpr_edge.encoders import Encoder
from vpr_edge.errors import InputError, VprError
from vpr_edge.features import FrontEnd

SHARD_BATCHES = 8       # batches a task describes and encodes (a shard of SHARD_BATCHES x batch_size frames)
CONNECT_TIMEOUT_S = 5.0


def check_ray(address: str) -> None:
    """Before the work: VprError unless Ray (the ``ray`` extra) is installed and, for an address other than
    ``local`` / ``auto``, something answers there (a TCP connection within ``CONNECT_TIMEOUT_S``)."""
    try:
        import ray  # noqa: F401
    except ImportError:
        raise InputError("{opt.ray} {address}: building on Ray needs Ray: pip install 'vpr-edge[ray]'",
                         address=address) from None
    if address in ("local", "auto"):
        return
    url = urlparse(address if "://" in address else f"ray://{address}")
    if not url.hostname or url.port is None:
        raise InputError("{opt.ray} {address}: expected local, auto or HOST:PORT (ray://HOST:PORT for Ray Client)",
                         address=address)
    try:
        with socket.create_connection((url.hostname, url.port), timeout=CONNECT_TIMEOUT_S):
            pass
    except OSError as e:
        raise InputError("{opt.ray} {address}: no Ray cluster answers there ({why})", address=address,
                         why=e.strerror or e) from None


def _connect(address: str):
    import ray

    if not ray.is_initialized():
        try:
            if address == "local":
                ray.init(include_dashboard=False, log_to_driver=False, configure_logging=False)
            else:
                ray.init(address=address, log_to_driver=False, configure_logging=False)
        except Exception as e:   # noqa: BLE001 - Ray raises many kinds; each is one line here
            raise InputError("{opt.ray} {address}: cannot join the Ray cluster ({why})", address=address,
                             why=str(e).splitlines()[0][:160]) from None
    return ray


def _encode_shard(paths: Sequence[str], order: np.ndarray, batch_size: int, front_name: str, front_spec: dict,
                  model: str | None, encoder_spec: dict, encoder_arrays: dict, input_dim: int
                  ) -> list[tuple[np.ndarray, np.ndarray]]:
    """On a worker: the images ``paths[order]``, in the build's batches of ``batch_size``, described by the
    front end the records give (``build.described``) and encoded: [(indices (b,), encodings (b, D) float32)]."""
    from vpr_edge.encoders import encoder_from_arrays
    from vpr_edge.features import make_front_end
    from vpr_edge.map.build import described

    front = make_front_end(front_name, Path(model) if model else None, 1, spec=front_spec)
    encoder = encoder_from_arrays(encoder_spec, encoder_arrays, input_dim, "the build's codebook")
    return [(idx, encoder.transform(x, m))
            for idx, x, m in described([Path(p) for p in paths], order, front, batch_size)]


def encode_on_ray(address: str, files: Sequence[Path], order: np.ndarray, front: FrontEnd, encoder: Encoder,
                  batch_size: int, progress=None) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """The images ``files[order]`` described and encoded on the Ray cluster at ``address`` in the plain
    build's batches of ``batch_size``: yields (indices (b,), encodings (b, D) float32) as shards finish.
    VprError naming the image for a frame that cannot be read, or saying which worker failed."""
    ray = _connect(address)
    from ray.exceptions import RayError, RayTaskError

    paths = [str(Path(f).resolve()) for f in files]
    model = front.identity().get("model_path")
    shard = SHARD_BATCHES * batch_size   # whole batches a shard: the plain build's batches
    task = ray.remote(max_retries=1)(_encode_shard)
    shared = ray.put(paths)
    spec = {"name": encoder.name, "params": encoder.params()}
    arrays = ray.put(encoder.to_arrays())
    pending = {task.remote(shared, order[i:i + shard], batch_size, front.name, front.describe(), model, spec,
                           arrays, encoder.input_dim): i for i in range(0, len(order), shard)}
    try:
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                pending.pop(ref)
                for idx, enc in ray.get(ref):
                    if progress:
                        progress(len(idx))
                    yield idx, enc
    except RayTaskError as e:
        cause = getattr(e, "cause", None)
        if isinstance(cause, VprError):
            raise VprError(str(cause)) from None
        raise InputError("{opt.ray} {address}: a task failed on a worker ({why}); nothing written",
                         address=address, why=str(e).splitlines()[0][:160]) from None
    except RayError as e:
        raise InputError("{opt.ray} {address}: a Ray worker failed mid-build ({why}); nothing written",
                         address=address, why=type(e).__name__) from None
    finally:
        for ref in pending:
            ray.cancel(ref, force=True)
