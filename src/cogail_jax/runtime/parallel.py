"""The seed axis, and each seed's env shards, over several devices: the jitted chunk of train steps, dispatched
per the state's sharding."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


class SeedChunk:
    """The jitted ``chunk(state, expert) -> (state, metrics)`` (``updates_per_call`` seed-vmapped train steps).

    When the state's seed axis is sharded over a mesh (``trainer.place_on_devices``), each device runs its own
    seeds as an independent program, in one of two ways (``multi``):

    * ``"shard_map"``: one SPMD program under ``shard_map``. Left to jit's sharding propagation instead, MJX's
      solver loops (whose stopping test reduces over the whole batch) put an all-reduce over the devices into
      every solver iteration, and two H200s ran handover at 0.25x the speed of one.
    * ``"per_device"``: the single-device program, compiled once per device and dispatched to all devices from
      a thread pool; its per-device outputs are put back together as the sharded state (the MJX tasks' default,
      from when their ``shard_map`` program crashed XLA's GPU compiler: that came from MJX's zero-size state
      fields, which now stay outside every program over several devices, ``_strip``).

    When the state's mesh also has an ``"envs"`` axis (a run's env shards over devices, ``algo.shards``), the chunk is
    ``env_fn`` under ``shard_map`` over both axes: each device runs its seeds' share of envs, and the updates average
    their gradients over ``"envs"`` (the only collectives: none inside the physics). ``env_leaves(state)`` tells which
    of the state's leaves have an env axis (after the seed axis).

    ``extra``: an array every call passes to ``fn`` / ``env_fn`` as a third argument (``fn(state, expert, extra)``),
    the same on every device: values the program takes as an argument instead of baking them in as constants
    (the update's hyperparameters, so that runs that differ only in them share one program).
    """

    def __init__(self, fn, multi: str = "shard_map", key=None, env_fn=None, env_leaves=None, extra=None):
        from .programs import stored

        self.fn = fn
        self.env_fn, self.env_leaves = env_fn, env_leaves
        self.multi = multi
        self.extra = None if extra is None else np.asarray(extra)
        self._extra_on: dict = {}  # the extra array placed, by device or mesh
        # one device: the program is kept between runs (programs.stored; ``key``: what ``fn`` closes over)
        self._plain = jax.jit(fn, donate_argnums=(0,)) if key is None else stored(fn, "chunk", key, (0,))
        self._sharded = {}
        self._pool = None

    @staticmethod
    def _mesh(state):
        from jax.sharding import NamedSharding

        sh = getattr(jax.tree.leaves(state)[0], "sharding", None)
        if not isinstance(sh, NamedSharding) or sh.mesh.size <= 1 or "seeds" not in sh.mesh.axis_names:
            return None
        return sh.mesh

    @staticmethod
    def _env_axis(mesh) -> bool:
        return mesh is not None and "envs" in mesh.axis_names and mesh.shape["envs"] > 1

    def _for(self, state):
        """The jitted program for ``state``'s layout; on a mesh it takes and returns the state less its empty
        leaves (``_strip``)."""
        from jax.sharding import PartitionSpec as P

        mesh = self._mesh(state)
        if mesh is None:
            return self._plain
        if mesh not in self._sharded:
            env = self._env_axis(mesh)
            fn = self.env_fn if env else self.fn
            flags = self.env_leaves(state) if env else jax.tree.map(lambda _: False, state)
            empty = _empty(state)
            blocks = {"seeds": mesh.shape["seeds"], "envs": mesh.shape["envs"] if env else 1}
            # an empty leaf's block on one device: its seeds' share (and env shard's) of a zero-size array
            local = jax.tree.map(lambda f, x: jax.ShapeDtypeStruct((x.shape[0] // blocks["seeds"],) + (
                (x.shape[1] // blocks["envs"],) + x.shape[2:] if f else x.shape[1:]), x.dtype), flags, state)
            specs = _strip(jax.tree.map(lambda f, _: P("seeds", "envs") if f else P("seeds"), flags, state), empty)

            def body(st, expert, *extra):
                st = jax.tree.map(lambda e, block, x: jnp.zeros(block.shape, block.dtype) if e else x, empty, local, st)
                st, metrics = fn(st, expert, *extra)
                return _strip(st, empty), metrics

            f = jax.shard_map(body, mesh=mesh, in_specs=(specs, P()) + ((P(),) if self.extra is not None else ()),
                              out_specs=(specs, P(None, "seeds")), check_vma=False)
            self._sharded[mesh] = (jax.jit(f, donate_argnums=(0,)), empty)
        return self._sharded[mesh]

    def _per_device(self, mesh, state, expert):
        from concurrent.futures import ThreadPoolExecutor

        from jax.sharding import NamedSharding, PartitionSpec as P

        n = mesh.devices.size
        devs = [d for d in mesh.devices.flat if d.process_index == jax.process_index()]  # this process's devices

        def shard(x, i):  # what device i holds of x
            return next(sh.data for sh in x.addressable_shards if sh.device == devs[i])

        def piece(x, i):  # device i's block of the seed axis (replicated empty leaves: an empty block)
            if x.size == 0:
                return jax.device_put(np.zeros((x.shape[0] // n,) + x.shape[1:], x.dtype), devs[i])
            return shard(x, i)

        def whole(parts, axis, pspec):  # (with several processes, the global array of every process's parts)
            shape = list(parts[0].shape)
            shape[axis] *= n
            if parts[0].size == 0:  # placed as trainer.place_on_devices places empty leaves: replicated
                return jax.device_put(np.zeros(shape, parts[0].dtype), NamedSharding(mesh, P()))
            return jax.make_array_from_single_device_arrays(tuple(shape), NamedSharding(mesh, pspec), list(parts))

        args = [(jax.tree.map(lambda x: piece(x, i), state), jax.tree.map(lambda x: shard(x, i), expert),
                 *self._extra(devs[i])) for i in range(len(devs))]
        del state
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=len(devs))
        outs = list(self._pool.map(lambda a: self._plain(*a), args))  # first call: the n compilations in parallel
        new_state = jax.tree.map(lambda *p: whole(p, 0, P("seeds")), *[o[0] for o in outs])
        metrics = jax.tree.map(lambda *p: whole(p, 1, P(None, "seeds")), *[o[1] for o in outs])
        return new_state, metrics

    def _extra(self, where) -> tuple:
        """``(extra,)`` placed on a device or replicated over a mesh (once), or ``()`` without one."""
        if self.extra is None:
            return ()
        if where not in self._extra_on:
            from jax.sharding import Mesh, NamedSharding, PartitionSpec as P

            if isinstance(where, Mesh):
                self._extra_on[where] = jax.make_array_from_callback(
                    self.extra.shape, NamedSharding(where, P()), lambda idx: self.extra[idx])
            else:
                self._extra_on[where] = jax.device_put(self.extra, where)
        return (self._extra_on[where],)

    @staticmethod
    def _device(state):
        """The device of a one-device state (``jax.ShapeDtypeStruct`` without a sharding: the first local one)."""
        sh = getattr(jax.tree.leaves(state)[0], "sharding", None)
        devices = getattr(sh, "device_set", None)
        return next(iter(devices)) if devices and len(devices) == 1 else jax.local_devices()[0]

    def __call__(self, state, expert):
        mesh = self._mesh(state)
        if mesh is not None and self.multi == "per_device" and not self._env_axis(mesh):
            return self._per_device(mesh, state, expert)
        f = self._for(state)
        if f is self._plain:
            return f(state, expert, *self._extra(self._device(state)))
        f, empty = f
        out, metrics = f(_strip(state, empty), expert, *self._extra(mesh))
        return jax.tree.map(lambda e, x, old: old if e else x, empty, out, state), metrics  # (empties: not donated)

    def lower(self, state, expert):
        f = self._for(state)
        if f is self._plain:
            return f.lower(state, expert, *self._extra(self._device(state)))
        return f[0].lower(_strip(state, f[1]), expert, *self._extra(self._mesh(state)))

    def _cache_size(self) -> int:
        return self._plain._cache_size() + sum(f._cache_size() for f, _ in self._sharded.values())


def _empty(tree):
    """True at every zero-size leaf of ``tree`` (MJX's unused fields, shape (seeds, envs, 0))."""
    return jax.tree.map(lambda x: x.size == 0, tree)


def _strip(tree, empty):
    """``tree`` without its empty leaves (None in their place): a program over several GPUs that takes or returns a
    zero-size array crashes XLA's GPU compiler (segmentation fault; JAX 0.11, 2 x H200), so they stay outside it
    and are made inside as zeros of each device's block shape. (Their values are kept: an empty array has none.)"""
    return jax.tree.map(lambda e, x: None if e else x, empty, tree)


__all__ = ["SeedChunk"]
