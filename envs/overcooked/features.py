"""The hand-made state features the field's behaviour clones of people read (Carroll et al., NeurIPS 2019: the
``featurize_state`` of overcooked_ai, which their BC models and H_proxy read), computed from an observation.

Per player, from the observing player's view (its own first, then its partner's): its facing (4, one-hot), what it
holds (onion, soup, plate: 3, one-hot), the (dx, dy) from it to the nearest onion (pile or loose; (0, 0) while it holds
one), empty pot, pot with one onion, pot with two, cooking pot, ready pot, plate (pile or loose; (0, 0) while it holds
one), loose soup ((0, 0) while it holds one) and serving spot (9 x 2; (0, 0) where there is none), whether the cell it
faces is an empty counter (1), and which of its four neighbours is not floor (4): 30. Then the partner's position
relative to the observer's and the observer's own (x, y): 64 in all. "Nearest" is by walking distance (shortest path
over floor cells to a cell beside the target; ties: the first target in row-major order), where overcooked_ai's
planner also counted the turns.
"""
from __future__ import annotations

from collections import deque

import jax
import jax.numpy as jnp
import numpy as np

from . import kitchen as kt

FEATURES = 64
_FAR = 10_000  # the distance to a target no floor path reaches

# observation planes (module docstring of env.py)
_POS, _OTHER_POS, _FACING, _OTHER_FACING = 0, 1, slice(2, 6), slice(6, 10)
_POT, _COUNTER, _ONION_PILE, _PLATE_PILE, _GOAL = 10, 11, 12, 14, 15
_ONIONS_IN_POT, _ONIONS_IN_SOUP, _READY, _PLATES, _ONIONS = 16, 18, 21, 22, 23
_STEPS = np.array([(0, -1), (0, 1), (1, 0), (-1, 0)])  # up, down, right, left (x, y; y down): the actions' order


def walking_costs(cells: np.ndarray) -> np.ndarray:
    """(C, C) for the kitchen's ``cells`` (H, W) grid (row-major index y * W + x): from a floor cell to a target cell,
    the fewest steps over floor cells to a floor cell beside the target; ``_FAR`` where none is reachable."""
    h, w = cells.shape
    floor = cells.reshape(-1) == kt.FLOOR
    n = h * w
    dist = np.full((n, n), _FAR, np.int64)
    for s in np.flatnonzero(floor):  # breadth-first from each floor cell
        dist[s, s] = 0
        queue = deque([s])
        while queue:
            c = queue.popleft()
            y, x = divmod(c, w)
            for dx, dy in _STEPS:
                xx, yy = x + dx, y + dy
                if 0 <= xx < w and 0 <= yy < h and floor[yy * w + xx] and dist[s, yy * w + xx] == _FAR:
                    dist[s, yy * w + xx] = dist[s, c] + 1
                    queue.append(yy * w + xx)
    cost = np.full((n, n), _FAR, np.int64)
    for t in range(n):
        y, x = divmod(t, w)
        beside = [(y + dy) * w + x + dx for dx, dy in _STEPS if 0 <= x + dx < w and 0 <= y + dy < h
                  and floor[(y + dy) * w + x + dx]]
        if beside:
            cost[:, t] = dist[:, beside].min(1)
    return cost


def make_featurize(cells: np.ndarray):
    """``featurize(obs) -> (FEATURES,)`` for observations (H x W x 26, flattened) of a kitchen of ``cells``."""
    h, w = cells.shape
    cost = jnp.asarray(walking_costs(cells), jnp.int32)
    xy = jnp.asarray(np.stack(np.meshgrid(np.arange(w), np.arange(h)), -1).reshape(-1, 2), jnp.int32)  # (C, 2)
    steps = jnp.asarray(_STEPS, jnp.int32)
    solid = jnp.asarray(cells.reshape(-1) != kt.FLOOR)

    def nearest(pos: jax.Array, targets: jax.Array) -> jax.Array:
        c = jnp.where(targets, cost[pos[1] * w + pos[0]], _FAR + 1)
        i = jnp.argmin(c)
        return jnp.where(c[i] <= _FAR, xy[i] - pos, 0).astype(jnp.float32)

    def player(g: jax.Array, pos: jax.Array, facing: jax.Array, loose: dict) -> jax.Array:
        here = pos[1] * w + pos[0]
        held = jnp.stack([g[here, _ONIONS], g[here, _READY], g[here, _PLATES]]) > 0  # onion, soup, plate
        pot = g[:, _POT] > 0
        cooking = pot & (g[:, _ONIONS_IN_SOUP] > 0) & (g[:, _READY] == 0)
        ready = pot & (g[:, _READY] > 0)
        idle = pot & ~cooking & ~ready
        deltas = [
            jnp.where(held[0], 0.0, nearest(pos, (g[:, _ONION_PILE] > 0) | loose["onion"])),
            nearest(pos, idle & (g[:, _ONIONS_IN_POT] == 0)),
            nearest(pos, idle & (g[:, _ONIONS_IN_POT] == 1)),
            nearest(pos, idle & (g[:, _ONIONS_IN_POT] == 2)),
            nearest(pos, cooking),
            nearest(pos, ready),
            jnp.where(held[2], 0.0, nearest(pos, (g[:, _PLATE_PILE] > 0) | loose["plate"])),
            jnp.where(held[1], 0.0, nearest(pos, loose["soup"])),
            nearest(pos, g[:, _GOAL] > 0),
        ]
        ahead = jnp.clip(pos + steps, 0, jnp.array([w - 1, h - 1]))
        inside = jnp.all((pos + steps >= 0) & (pos + steps < jnp.array([w, h])), -1)
        around = ahead[:, 1] * w + ahead[:, 0]
        wall = ~inside | solid[around]
        front = around[jnp.argmax(facing)]
        empty_counter = (g[front, _COUNTER] > 0) & ~(loose["onion"] | loose["plate"] | loose["soup"])[front]
        return jnp.concatenate([facing, held.astype(jnp.float32), *deltas, empty_counter[None].astype(jnp.float32),
                                wall.astype(jnp.float32)])

    def featurize(obs: jax.Array) -> jax.Array:
        g = obs.reshape(h * w, -1)
        pos = [xy[jnp.argmax(g[:, p])] for p in (_POS, _OTHER_POS)]
        facing = [g[jnp.argmax(g[:, p]), s] for p, s in ((_POS, _FACING), (_OTHER_POS, _OTHER_FACING))]
        on_agent = (g[:, _POS] > 0) | (g[:, _OTHER_POS] > 0)
        loose = {"onion": (g[:, _ONIONS] > 0) & ~on_agent, "plate": (g[:, _PLATES] > 0) & ~on_agent,
                 "soup": (g[:, _READY] > 0) & (g[:, _POT] == 0) & ~on_agent}
        me, other = (player(g, pos[i], facing[i], loose) for i in (0, 1))
        return jnp.concatenate([me, other, (pos[1] - pos[0]).astype(jnp.float32), pos[0].astype(jnp.float32)])

    return featurize
