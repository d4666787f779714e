"""Choosing where episodes run: `open_backend("local" | "ray", ...)`.

The local backend (terl_rt.evaluation.pool) needs nothing more than terl_rt; the Ray
backend (terl_rt.evaluation.ray_backend) needs Ray, the `ray` extra, imported only here
and only when it is asked for.
"""

from __future__ import annotations

from terl_rt.evaluation.play import BATCH_ENVS
from terl_rt.evaluation.pool import LocalBackend
from terl_rt.evaluation.runs import Backend
from terl_rt.extras import install_hint

BACKENDS = ("local", "ray")
RAY_INSTALL_HINT = install_hint("ray")


class RayMissing(ImportError):
    """The Ray backend was asked for and Ray is not installed; the message says how to install it."""


def open_backend(name: str, workers: int | None = None, address: str | None = None,
                 threads: int | None = None, envs: int = BATCH_ENVS) -> Backend:
    """The backend `name` ("local" or "ray"), ready to run episodes; close it with `close()`
    (or a `with` block) when done.

    workers: batches at once (local default 1; Ray default every CPU of the cluster);
    envs: episodes a batch runs at once, in one World.
    address: the Ray cluster to join (Ray only; None starts a local Ray instance).
    threads: onnxruntime intra-op threads per worker. Raises RayMissing without Ray and
    terl_rt.evaluation.runs.BackendError when a cluster cannot be reached.
    """
    if name not in BACKENDS:
        raise ValueError(f"backend must be one of {', '.join(BACKENDS)}, got {name!r}")
    if name == "local":
        if address is not None:
            raise ValueError("an address names a Ray cluster; it needs the ray backend")
        return LocalBackend(workers or 1, threads, envs)
    try:
        from terl_rt.evaluation.ray_backend import RayBackend
    except ModuleNotFoundError as error:
        if error.name != "ray" and not str(error.name).startswith("ray."):
            raise
        raise RayMissing(f"the ray backend needs Ray, which is not installed; install it with: {RAY_INSTALL_HINT}") from None
    return RayBackend(address, workers, threads, envs)
