"""Segment sums over static ids as gathers, for MJX's sums over the kinematic tree.

MJX sums quantities from child bodies into their parents with ``jax.ops.segment_sum(x, ids, n)``, where
``ids`` is a numpy array fixed by the model. That is a scatter-add with repeated indices, and with
deterministic GPU execution (``--xla_gpu_deterministic_ops``, the default of every ``cogail`` command) XLA
runs each such scatter as a serial loop over its indices: on HR-Handover's paper layout (H100) an update took
287 ms with them, 214 ms with the gathers below, and 191 ms without deterministic execution.
:func:`static_segment_sum` computes the same sums with gathers and additions in the order of the ids (segment
``s`` is ``((0 + x[i0]) + x[i1]) + ...`` over its members ``i0 < i1 < ...``), which is deterministic without
any scatter. :func:`gathered_segment_sums` routes ``jax.ops.segment_sum`` calls with static ids to it while a
function is traced.
"""
from __future__ import annotations

import contextlib
import threading
from typing import Iterator

import jax
import jax.numpy as jnp
import numpy as np

_SEGMENT_SUM = jax.ops.segment_sum  # JAX's own, kept for every call this module does not handle


def static_segment_sum(data: jax.Array, ids: np.ndarray, num_segments: int) -> jax.Array:
    """``jax.ops.segment_sum(data, ids, num_segments)`` for static ``ids`` in ``[0, num_segments)``, by gathers:
    the j-th member of every segment is gathered and added in turn (no scatter)."""
    ids = np.asarray(ids)
    members = [np.flatnonzero(ids == s) for s in range(num_segments)]
    depth = max((len(m) for m in members), default=0)
    out = jnp.zeros((num_segments,) + data.shape[1:], data.dtype)
    mask_shape = (num_segments,) + (1,) * (data.ndim - 1)
    for j in range(depth):
        rows = np.array([m[j] if j < len(m) else 0 for m in members], dtype=np.int32)
        has = np.array([j < len(m) for m in members]).reshape(mask_shape)
        out = out + jnp.where(has, data[rows], jnp.zeros((), data.dtype))
    return out


def _segment_sum(data, segment_ids, num_segments=None, *args, **kwargs):
    static = (isinstance(segment_ids, np.ndarray) and segment_ids.ndim == 1 and segment_ids.size > 0
              and isinstance(num_segments, (int, np.integer)) and not args and not kwargs
              and np.issubdtype(segment_ids.dtype, np.integer)
              and segment_ids.min() >= 0 and segment_ids.max() < num_segments
              and jnp.ndim(data) >= 1 and jnp.shape(data)[0] == segment_ids.size)
    if static:
        return static_segment_sum(jnp.asarray(data), segment_ids, int(num_segments))
    return _SEGMENT_SUM(data, segment_ids, num_segments, *args, **kwargs)


_LOCK = threading.Lock()
_ACTIVE = 0  # contexts open, over all threads


@contextlib.contextmanager
def gathered_segment_sums() -> Iterator[None]:
    """While tracing inside this context, ``jax.ops.segment_sum`` with numpy ids computes by gathers
    (:func:`static_segment_sum`); any other call goes to JAX's own. JAX's function is put back when the last
    context open (in any thread: programs may be traced in a background thread) closes."""
    global _ACTIVE
    with _LOCK:
        _ACTIVE += 1
        jax.ops.segment_sum = _segment_sum
    try:
        yield
    finally:
        with _LOCK:
            _ACTIVE -= 1
            if not _ACTIVE:
                jax.ops.segment_sum = _SEGMENT_SUM
