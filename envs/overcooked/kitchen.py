"""The five kitchens of Overcooked-AI on JaxMARL's grids, and the init vector that encodes a whole game state.

A kitchen's static geometry (:class:`Kitchen`) comes from JaxMARL's layout: the grid's walls, pots, onion and
plate piles, serving spots and the counter cells (every wall cell that is none of these: where an item can be
put down). Kitchens go by the names of the paper's figures; the trials' data names two of them otherwise::

    our name               JaxMARL layout      data layout_name
    cramped_room           cramped_room        cramped_room
    asymmetric_advantages  asymm_advantages    asymmetric_advantages
    coordination_ring      coord_ring          coordination_ring
    forced_coordination    forced_coord        random0
    counter_circuit        counter_circuit     random3

Init vector (float32, integers stored as floats; P pots, C counter cells, both in :class:`Kitchen`'s order)::

    [0:4]            x0, y0, x1, y1          both agents' cells (x right, y down; agent 0 = human, 1 = robot)
    [4:6]            dir0, dir1              facing: 0 up, 1 down, 2 right, 3 left (the move actions' ids)
    [6:8]            held0, held1            item code (ITEMS): 0 nothing, 1 onion, 2 plate, 3 soup (on a plate)
    [8:8+P]          onions in each pot      0..3
    [8+P:8+2P]       each pot's cook steps left: 20 until the pot holds 3 onions, then 19 .. 0 (0 = ready)
    [8+2P:8+2P+C]    item code on each counter cell

Start cells: every trial of the people's data starts with player 0 (our human) on the layout's cell ``1`` and
player 1 on ``2`` (:data:`TRIAL_STARTS`), facing up. JaxMARL's layouts start elsewhere in four kitchens, in two of
them (asymmetric advantages, forced coordination) with the agents on the other's side of the wall
(``Kitchen.jaxmarl_start``); the task starts where the trials do.

:func:`state_from_init` builds JaxMARL's state from it and :func:`init_from_state` reads it back (jittable; the
two are inverse for every state a game can reach).
"""
from __future__ import annotations

import contextlib
import functools
import io
import warnings
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

KITCHENS = {
    "cramped_room": ("cramped_room", "cramped_room"),
    "asymmetric_advantages": ("asymm_advantages", "asymmetric_advantages"),
    "coordination_ring": ("coord_ring", "coordination_ring"),
    "forced_coordination": ("forced_coord", "random0"),
    "counter_circuit": ("counter_circuit", "random3"),
}
# the cells (x, y) of player 0 and player 1 at the start of every trial (the data's layouts' "1" and "2")
TRIAL_STARTS = {
    "cramped_room": ((1, 2), (3, 1)),
    "asymmetric_advantages": ((6, 2), (1, 3)),
    "coordination_ring": ((2, 1), (1, 2)),
    "forced_coordination": ((3, 1), (1, 2)),
    "counter_circuit": ((6, 3), (1, 3)),
}
ITEMS = ("nothing", "onion", "plate", "soup")
COOK_STEPS = 20  # a full pot's soup is ready 20 steps after its third onion
MAX_ONIONS = 3
# JaxMARL's object ids (jaxmarl.environments.overcooked.common.OBJECT_TO_INDEX), fixed by its 0.2.0 release
EMPTY, WALL, ONION, ONION_PILE, PLATE, PLATE_PILE, GOAL, POT, DISH, AGENT = 1, 2, 3, 4, 5, 6, 7, 8, 9, 10
ITEM_OBJECT = np.array([EMPTY, ONION, PLATE, DISH], np.int32)  # item code -> JaxMARL object id (in a hand)
OBJECT_ITEM = np.zeros(11, np.int32)  # JaxMARL object id -> item code (anything else: nothing)
OBJECT_ITEM[[ONION, PLATE, DISH]] = (1, 2, 3)
POT_EMPTY = 23  # JaxMARL pot status: 23 - onions until full, then the cook steps left (20 .. 0)
# cell types of the static grid (Kitchen.cells)
FLOOR, COUNTER, POT_CELL, ONION_CELL, PLATE_CELL, GOAL_CELL = range(6)
PAD = 4  # JaxMARL pads its maze map by agent_view_size - 1 = 4 cells on each side


@functools.lru_cache(maxsize=None)
def jaxmarl_overcooked():
    """JaxMARL's v1 Overcooked module, imported on first use (its package prints a line and warns on import)."""
    import os
    import sys

    sys.stdout.flush()
    saved = os.dup(1)  # at the descriptor: a module it imports on the way swaps sys.stdout back
    try:
        with open(os.devnull, "w") as null, contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings():
            os.dup2(null.fileno(), 1)
            warnings.simplefilter("ignore")
            from jaxmarl.environments.overcooked import overcooked
            sys.stdout.flush()
    finally:
        os.dup2(saved, 1)
        os.close(saved)
    return overcooked


def jaxmarl_game(kitchen: str, max_steps: int):
    """JaxMARL's ``Overcooked`` on the kitchen's layout, without its deprecation warning."""
    mod = jaxmarl_overcooked()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return mod.Overcooked(layout=mod.layouts[KITCHENS[kitchen][0]], max_steps=int(max_steps))


def _xy(idx, width: int) -> np.ndarray:
    idx = np.asarray(idx, np.int64).reshape(-1)
    return np.stack([idx % width, idx // width], -1).astype(np.int32)


@dataclass(frozen=True, eq=False)
class Kitchen:
    """A kitchen's static geometry (numpy; cells as (x, y) with y down)."""

    name: str
    height: int
    width: int
    cells: np.ndarray  # (H, W) cell type: FLOOR, COUNTER, POT_CELL, ONION_CELL, PLATE_CELL, GOAL_CELL
    pots: np.ndarray  # (P, 2) in JaxMARL's order
    goals: np.ndarray  # (G, 2) serving spots
    onion_piles: np.ndarray
    plate_piles: np.ndarray
    counters: np.ndarray  # (C, 2) counter cells, row-major
    start: np.ndarray  # (2, 2) the trials' start cells of agent 0 (human) and agent 1 (robot)
    jaxmarl_start: np.ndarray  # (2, 2) JaxMARL's start cells of agent_0 and agent_1
    base_map: np.ndarray  # JaxMARL's padded maze map with no agents, no items and empty pots

    @property
    def num_pots(self) -> int:
        return len(self.pots)

    @property
    def num_counters(self) -> int:
        return len(self.counters)

    @property
    def init_size(self) -> int:
        return 8 + 2 * self.num_pots + self.num_counters

    def init_slices(self) -> dict[str, slice]:
        """Name -> slice of the init vector (the module docstring's layout)."""
        p, c = self.num_pots, self.num_counters
        return {"pos": slice(0, 4), "dir": slice(4, 6), "held": slice(6, 8), "pot_onions": slice(8, 8 + p),
                "pot_timer": slice(8 + p, 8 + 2 * p), "counters": slice(8 + 2 * p, 8 + 2 * p + c)}


@functools.lru_cache(maxsize=None)
def kitchen_geometry(kitchen: str) -> Kitchen:
    """The static geometry of one of :data:`KITCHENS`."""
    if kitchen not in KITCHENS:
        raise ValueError(f"unknown kitchen {kitchen!r}: choose one of {', '.join(KITCHENS)}")
    mod = jaxmarl_overcooked()
    lay = mod.layouts[KITCHENS[kitchen][0]]
    h, w = int(lay["height"]), int(lay["width"])
    cells = np.full(h * w, FLOOR, np.int32)
    cells[np.asarray(lay["wall_idx"])] = COUNTER
    for key, kind in (("pot_idx", POT_CELL), ("onion_pile_idx", ONION_CELL), ("plate_pile_idx", PLATE_CELL),
                      ("goal_idx", GOAL_CELL)):
        cells[np.asarray(lay[key])] = kind
    counters = np.flatnonzero(cells == COUNTER)
    # JaxMARL's padded maze map as its reset draws it (object id, colour, pot status per cell), without agents
    vec = np.asarray(mod.OBJECT_INDEX_TO_VEC)
    base = np.tile(vec[WALL], (h + 2 * PAD, w + 2 * PAD, 1))
    objects = {FLOOR: EMPTY, COUNTER: WALL, POT_CELL: POT, ONION_CELL: ONION_PILE, PLATE_CELL: PLATE_PILE,
               GOAL_CELL: GOAL}
    base[PAD:PAD + h, PAD:PAD + w] = vec[np.vectorize(objects.get)(cells.reshape(h, w))]
    base[PAD:PAD + h, PAD:PAD + w, 2] = np.where(cells.reshape(h, w) == POT_CELL, POT_EMPTY, 0)
    return Kitchen(
        name=kitchen, height=h, width=w, cells=cells.reshape(h, w), pots=_xy(lay["pot_idx"], w),
        goals=_xy(lay["goal_idx"], w), onion_piles=_xy(lay["onion_pile_idx"], w),
        plate_piles=_xy(lay["plate_pile_idx"], w), counters=_xy(counters, w),
        start=np.array(TRIAL_STARTS[kitchen], np.int32), jaxmarl_start=_xy(lay["agent_idx"], w), base_map=base,
    )


def state_from_init(k: Kitchen, init: jax.Array):
    """JaxMARL's state (step 0) of the game state an init vector encodes (jittable)."""
    mod = jaxmarl_overcooked()
    obj_vec = mod.OBJECT_INDEX_TO_VEC
    sl = k.init_slices()
    i = jnp.round(jnp.asarray(init, jnp.float32)).astype(jnp.int32)
    pos = i[sl["pos"]].reshape(2, 2)
    dirs = jnp.clip(i[sl["dir"]], 0, 3)
    held = jnp.clip(i[sl["held"]], 0, 3)
    onions = jnp.clip(i[sl["pot_onions"]], 0, MAX_ONIONS)
    timer = jnp.clip(i[sl["pot_timer"]], 0, COOK_STEPS)
    on_counter = jnp.clip(i[sl["counters"]], 0, 3)
    status = jnp.where(onions >= MAX_ONIONS, timer, POT_EMPTY - onions).astype(jnp.uint8)
    maze = jnp.asarray(k.base_map)
    if k.num_counters:
        items = jnp.where(on_counter > 0, jnp.asarray(ITEM_OBJECT)[on_counter], WALL)
        maze = maze.at[PAD + k.counters[:, 1], PAD + k.counters[:, 0]].set(obj_vec[items])
    maze = maze.at[PAD + k.pots[:, 1], PAD + k.pots[:, 0], 2].set(status)
    agents = jnp.stack([jnp.full((2,), AGENT), jnp.arange(2) * 2, dirs], -1).astype(jnp.uint8)  # red + 2 i
    maze = maze.at[PAD + pos[:, 1], PAD + pos[:, 0]].set(agents)
    return mod.State(
        agent_pos=pos.astype(jnp.uint32), agent_dir=mod.DIR_TO_VEC[dirs], agent_dir_idx=dirs.astype(jnp.int32),
        agent_inv=jnp.asarray(ITEM_OBJECT)[held], goal_pos=jnp.asarray(k.goals, jnp.uint32),
        pot_pos=jnp.asarray(k.pots, jnp.uint32), wall_map=jnp.asarray(k.cells != FLOOR), maze_map=maze,
        step=jnp.zeros((), jnp.int32), done=jnp.zeros((), bool),
    )


def init_from_state(k: Kitchen, ps) -> jax.Array:
    """The init vector of a JaxMARL state (jittable; :func:`state_from_init`'s inverse)."""
    maze = ps.maze_map
    status = maze[PAD + k.pots[:, 1], PAD + k.pots[:, 0], 2].astype(jnp.int32)
    onions = jnp.where(status > COOK_STEPS, POT_EMPTY - status, MAX_ONIONS)
    timer = jnp.where(status > COOK_STEPS, COOK_STEPS, status)
    item_of = jnp.asarray(OBJECT_ITEM)
    on_counter = item_of[maze[PAD + k.counters[:, 1], PAD + k.counters[:, 0], 0].astype(jnp.int32)]
    parts = [ps.agent_pos.reshape(-1), ps.agent_dir_idx, item_of[ps.agent_inv], onions, timer, on_counter]
    return jnp.concatenate([jnp.asarray(p, jnp.float32).reshape(-1) for p in parts])


def start_init(k: Kitchen, dirs: jax.Array, cells: np.ndarray | None = None) -> jax.Array:
    """The init vector of a game's start: the agents on ``cells`` (2, 2) (default: the trials' start cells) facing
    ``dirs`` (2,), empty hands, pots and counters."""
    p, c = k.num_pots, k.num_counters
    cells = k.start if cells is None else cells
    return jnp.concatenate([jnp.asarray(cells, jnp.float32).reshape(-1), jnp.asarray(dirs, jnp.float32),
                            jnp.zeros((2 + p,)), jnp.full((p,), float(COOK_STEPS)), jnp.zeros((c,))])
