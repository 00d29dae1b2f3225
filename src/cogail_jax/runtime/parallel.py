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
      a thread pool; its per-device outputs are put back together as the sharded state. On 2 x H200 XLA's GPU
      compiler crashes (segmentation fault inside ``backend_compile_and_load``) on the 2-device ``shard_map``
      program of the MJX tasks, while their single-device program compiles.

    When the state's mesh also has an ``"envs"`` axis (a run's env shards over devices, ``algo.shards``), the chunk is
    ``env_fn`` under ``shard_map`` over both axes: each device runs its seeds' share of envs, and the updates average
    their gradients over ``"envs"`` (the only collectives: none inside the physics). ``env_leaves(state)`` tells which
    of the state's leaves have an env axis (after the seed axis). With ``multi="per_device"`` (the physics cannot
    be compiled into a program over several GPUs) the update is split instead (``split = ((collect, learn, join),
    updates)``, from ``train.split_step``): each device steps its envs in its own one-device program (``collect``,
    given the device's shard index), the batches are put together as arrays over the mesh, and ``learn`` runs
    under ``shard_map`` with the gradient averages on the state less its env state (which holds MJX's empty
    fields; ``join`` puts it back); the host repeats that ``updates`` times per call.
    """

    def __init__(self, fn, multi: str = "shard_map", key=None, env_fn=None, env_leaves=None, split=None):
        from .programs import stored

        self.fn = fn
        self.env_fn, self.env_leaves = env_fn, env_leaves
        self.multi = multi
        # one device: the program is kept between runs (programs.stored; ``key``: what ``fn`` closes over)
        self._plain = jax.jit(fn, donate_argnums=(0,)) if key is None else stored(fn, "chunk", key, (0,))
        self._sharded = {}
        self._pool = None
        self.split = split
        self._collect = None if split is None else jax.jit(split[0][0], donate_argnums=(0,))
        self._learn = {}

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
        from jax.sharding import PartitionSpec as P

        mesh = self._mesh(state)
        if mesh is None:
            return self._plain
        if mesh not in self._sharded:
            if self._env_axis(mesh):
                # (empty leaves too, though placed replicated: shard_map hands each device its block's shape)
                specs = jax.tree.map(lambda f, x: P("seeds", "envs") if f else P("seeds"), self.env_leaves(state), state)
                f = jax.shard_map(self.env_fn, mesh=mesh, in_specs=(specs, P()), out_specs=(specs, P(None, "seeds")),
                                  check_vma=False)
            else:
                f = jax.shard_map(self.fn, mesh=mesh, in_specs=(P("seeds"), P()),
                                  out_specs=(P("seeds"), P(None, "seeds")), check_vma=False)
            self._sharded[mesh] = jax.jit(f, donate_argnums=(0,))
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

        args = [(jax.tree.map(lambda x: piece(x, i), state), jax.tree.map(lambda x: shard(x, i), expert))
                for i in range(len(devs))]
        del state
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=len(devs))
        outs = list(self._pool.map(lambda a: self._plain(*a), args))  # first call: the n compilations in parallel
        new_state = jax.tree.map(lambda *p: whole(p, 0, P("seeds")), *[o[0] for o in outs])
        metrics = jax.tree.map(lambda *p: whole(p, 1, P(None, "seeds")), *[o[1] for o in outs])
        return new_state, metrics

    def _split(self, mesh, state, expert):
        from concurrent.futures import ThreadPoolExecutor

        from jax.sharding import NamedSharding, PartitionSpec as P

        collect, ((_, learn_fn, join), updates) = self._collect, self.split
        axis = "seeds" if mesh.shape["seeds"] > 1 else None  # as place_on_devices: placements kept call to call
        env, seeds = P(axis, "envs"), P(axis) if axis else P()
        specs = jax.tree.map(lambda f, _: env if f else seeds, self.env_leaves(state), state)
        rest_specs = jax.tree.map(lambda f, _: env if f else seeds, self.env_leaves(join(state, None)),
                                  join(state, None))
        if mesh not in self._learn:
            f = jax.shard_map(learn_fn, mesh=mesh, in_specs=(rest_specs, env, P()), out_specs=(rest_specs, seeds),
                              check_vma=False)
            self._learn[mesh] = jax.jit(f, donate_argnums=(0, 1))
        learn = self._learn[mesh]
        devs = [d for d in mesh.devices.flat if d.process_index == jax.process_index()]  # this process's devices
        at = {d: jax.device_put(np.int32(np.argwhere(mesh.devices == d)[0][1]), d) for d in devs}
        size = {"seeds": mesh.shape["seeds"], "envs": mesh.shape["envs"]}

        def piece(x, spec, d):  # what device d holds of x (of an empty leaf, placed replicated: its block's shape)
            if x.size == 0:
                shape = [n // size.get(a, 1) for n, a in zip(x.shape, tuple(spec) + (None,) * x.ndim)]
                return jax.device_put(np.zeros(shape, x.dtype), d)
            return next(sh.data for sh in x.addressable_shards if sh.device == d)

        def whole(spec, *parts):  # the array over the mesh of every device's part (every process's, with several)
            shape = [n * size.get(a, 1) for n, a in zip(parts[0].shape, tuple(spec) + (None,) * parts[0].ndim)]
            if parts[0].size == 0:  # placed as trainer.place_on_devices places empty leaves: replicated
                return jax.device_put(np.zeros(shape, parts[0].dtype), NamedSharding(mesh, P()))
            return jax.make_array_from_single_device_arrays(tuple(shape), NamedSharding(mesh, spec), list(parts))

        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=len(devs))
        metrics = []
        for _ in range(updates):
            args = [(jax.tree.map(lambda sp, x: piece(x, sp, d), specs, state), at[d]) for d in devs]
            del state
            outs = list(self._pool.map(lambda a: collect(*a), args))  # first call: the compilations in parallel
            del args
            env_state = jax.tree.map(lambda *p: whole(env, *p), *[o[0] for o in outs])
            rest = jax.tree.map(whole, rest_specs, *[o[1] for o in outs])
            batch = jax.tree.map(lambda *p: whole(env, *p), *[o[2] for o in outs])
            del outs
            rest, m = learn(rest, batch, expert)
            state = join(rest, env_state)
            metrics.append(m)
        return state, jax.tree.map(lambda *m: jnp.stack(m), *metrics)

    def __call__(self, state, expert):
        mesh = self._mesh(state)
        if mesh is not None and self.multi == "per_device":
            if self._env_axis(mesh):
                return self._split(mesh, state, expert)
            return self._per_device(mesh, state, expert)
        return self._for(state)(state, expert)

    def lower(self, state, expert):
        mesh = self._mesh(state)
        if self.multi == "per_device" and self._env_axis(mesh):
            raise NotImplementedError("the split update's programs compile on its first call")
        return self._for(state).lower(state, expert)

    def _cache_size(self) -> int:
        split = 0 if self._collect is None else self._collect._cache_size() + sum(
            f._cache_size() for f in self._learn.values())
        return self._plain._cache_size() + sum(f._cache_size() for f in self._sharded.values()) + split


__all__ = ["SeedChunk"]
