"""The variations of a scripted team's human, shared by the tasks' teams (``<task>/team.py``).

A task's team (:class:`cogail_envs.registry.Team`) is ``init(env, rng, mix, variation=0)`` and
``act(env, team_state, state, rng)`` (pure JAX, vmappable). The env modules keep the physics, the
observation, ``classify_strategy`` and ``render``.

``variation`` (an int, or a traced int32 so that one compiled rollout serves them all) changes the scripted
HUMAN only; the scripted robot keeps reacting to what the human actually does. 0 = none (the default
demonstrations, drawn exactly as before variations existed: their randomness comes from keys folded off
the ones the default team uses). The ids, in order (``VARIATIONS[i - 1]`` is id ``i``):

* ``slow`` / ``fast`` -- the human's pace (speed, acceleration and gain limits scaled, within the action
  bounds);
* ``pauses`` -- the human stops dead for a few dozen steps at random times (its plan frozen meanwhile);
* ``detour`` -- the human's path goes via random waypoints / approaches from other angles;
* ``noise`` -- larger action noise on the human;
* ``change_of_mind`` -- the human first heads for another strategy's target for a while, then does its own.

What each means per task is in the task's team module (``<task>/team.py``).

``variation | FOLLOWING_PARTNER`` (teams with ``partner_can_follow``) changes the
scripted ROBOT instead of reading the team's plan: under ``change_of_mind`` it first takes the strategy the
human's moves suggest and switches when the human turns to its own, as a partner who cannot read minds does.
Training sets use it (``robustness.ensure_varied_training_set``) so that the demonstrations show a robot
recovering from a wrong guess; the test and validation humans are recorded with the robot that reads the plan.

``variation | PROMPT_ROBOT`` (teams with ``prompt_robot``) makes the scripted ROBOT the team's most prompt
demonstrator: the top of its speed, acceleration and gain ranges and the shortest of its reaction delays, the
human and everything else drawn as without it. The training split's demonstrations use it (``cogail_jax.data``):
the learned robot imitates a partner who does not keep the person waiting, and the recorded humans of the test and
validation splits, who let go when their own (varied) partner had taken the object, are not waiting for a robot
slower than theirs.

``variation | POSE_HELDOUT`` (teams with ``held_out``) draws the episode's object pose and hand-over place from the
team's held-out slices (a band beyond each range, e.g. the outer third of the carry angle) instead of its training
ranges: every default, training, validation and test episode lies in the training ranges, and the held-out evaluation
sets measure generalisation beyond them. One slice per degree of freedom the team varies (:data:`POSE_AXES`: the
object turned about each of its three axes, the place moved along each of the world's, and the place the object is
put down at): ``variation | pose_slice(axis)`` (the set ``pose_heldout_<axis>``, :func:`slice_name`) moves that one
beyond its range and keeps every other in range; ``variation | POSE_HELDOUT`` alone (``pose_heldout``) moves one of
the team's axes, drawn per episode. What the ranges are: the team's module (``Team.held_out_slices``: its axes).
"""
from __future__ import annotations

import jax
import jax.numpy as jnp

VARIATIONS = ("slow", "fast", "pauses", "detour", "noise", "change_of_mind")
NONE, SLOW, FAST, PAUSES, DETOUR, NOISE, CHANGE_OF_MIND = range(7)
FOLLOWING_PARTNER = 8  # flag bit on a variation id: the scripted robot follows the human's apparent strategy
POSE_HELDOUT = 16      # flag bit: the human presents the object in the team's held-out pose / place slice
PROMPT_ROBOT = 32      # flag bit: the scripted robot is the team's most prompt demonstrator (the training split's)
HELD_OUT = "pose_heldout"  # the name of that slice's evaluation set (teams with ``held_out``)
# the degrees of freedom a held-out slice can move (roll, pitch, yaw: the object turned about its long axis, tilted,
# turned about the vertical; x, y, z: the hand-over place moved along the world's axes; place: where the object is put
# down); their id sits in the bits from SLICE_SHIFT up (0: any of the team's, drawn per episode)
POSE_AXES = ("roll", "pitch", "yaw", "x", "y", "z", "place")
SLICE_SHIFT = 6

# salt for the variation's own random draws (fold_in of the team key): the default draws stay as they were
VARIATION_SALT = 7_777


def variation_id(variation: int | str | None) -> int:
    """``None`` / ``"none"`` -> 0, a name of :data:`VARIATIONS` -> its id (1..6), ``"pose_heldout"`` ->
    :data:`POSE_HELDOUT`, an int -> itself."""
    if variation is None:
        return NONE
    if isinstance(variation, str):
        if variation == "none":
            return NONE
        if variation == HELD_OUT:
            return POSE_HELDOUT
        if variation.startswith(HELD_OUT + "_") and variation[len(HELD_OUT) + 1:] in POSE_AXES:
            return pose_slice(variation[len(HELD_OUT) + 1:])
        if variation not in VARIATIONS:
            raise ValueError(f"unknown variation {variation!r}: choose one of {', '.join(VARIATIONS)}, "
                             f"{HELD_OUT} or {HELD_OUT}_<axis> with an axis of {', '.join(POSE_AXES)}")
        return VARIATIONS.index(variation) + 1
    return int(variation)


def pose_slice(axis: str) -> int:
    """The variation flags of the held-out slice of one degree of freedom (``axis`` of :data:`POSE_AXES`)."""
    if axis not in POSE_AXES:
        raise ValueError(f"unknown pose axis {axis!r}: choose one of {', '.join(POSE_AXES)}")
    return POSE_HELDOUT | ((POSE_AXES.index(axis) + 1) << SLICE_SHIFT)


def slice_name(axis: str) -> str:
    """The evaluation set of one axis' held-out slice, ``pose_heldout_<axis>``."""
    pose_slice(axis)
    return f"{HELD_OUT}_{axis}"


def slice_names(axes) -> tuple[str, ...]:
    return tuple(slice_name(a) for a in axes)


def held_out_sets(team) -> tuple[str, ...]:
    """The held-out evaluation sets of a team (:class:`cogail_envs.Team`): ``pose_heldout_<axis>`` for each axis of
    its ``held_out_slices``, ``pose_heldout`` for a team that draws a held-out slice without naming its axes, none
    for one without ``held_out``."""
    if team is None or not getattr(team, "held_out", False):
        return ()
    axes = tuple(getattr(team, "held_out_slices", ()) or ())
    return slice_names(axes) if axes else (HELD_OUT,)


def is_held_out_set(name: str) -> bool:
    """Whether ``name`` is a held-out pose slice's set (``pose_heldout`` or ``pose_heldout_<axis>``)."""
    return name == HELD_OUT or (name.startswith(HELD_OUT + "_") and name[len(HELD_OUT) + 1:] in POSE_AXES)


def held_axes(key: jax.Array, variation, axes: tuple[str, ...]) -> dict[str, jax.Array]:
    """Per axis of a team's ``axes`` (its ``held_out_slices``), whether this episode draws it from its held-out slice:
    none without :data:`POSE_HELDOUT`; the one the variation names (:func:`pose_slice`); with the flag alone, one of
    ``axes`` drawn with ``key``. Traced ``variation`` welcome."""
    v = jnp.asarray(variation, jnp.int32)
    k = (v >> SLICE_SHIFT) & 7  # 0: any, else POSE_AXES index + 1
    drawn = jnp.asarray([POSE_AXES.index(a) + 1 for a in axes], jnp.int32)[
        jax.random.randint(key, (), 0, len(axes))]
    chosen = jnp.where(k == 0, drawn, k)
    return {a: held_out(v) & (chosen == POSE_AXES.index(a) + 1) for a in axes}


def band_draw(key: jax.Array, held, inner: tuple[float, float], below: tuple[float, float] | None = None,
              above: tuple[float, float] | None = None) -> jax.Array:
    """A value uniform over ``inner`` (the training range), or where ``held`` over a band beyond it: ``below``
    (under ``inner[0]``) or ``above`` (over ``inner[1]``), at even odds where both are given."""
    k1, k2, k3, k4 = jax.random.split(key, 4)
    a = jax.random.uniform(k1, (), minval=inner[0], maxval=inner[1])
    outs = [jax.random.uniform(k, (), minval=b[0], maxval=b[1]) for k, b in ((k2, below), (k3, above)) if b]
    b = outs[0] if len(outs) == 1 else jnp.where(jax.random.bernoulli(k4, 0.5), outs[0], outs[1])
    return jnp.where(held, b, a)


def human_variation(variation) -> jax.Array:
    """The variation id without its flag bits (:data:`FOLLOWING_PARTNER`, :data:`POSE_HELDOUT` and its axis,
    :data:`PROMPT_ROBOT`)."""
    return jnp.asarray(variation, jnp.int32) % FOLLOWING_PARTNER


def held_out(variation) -> jax.Array:
    """Whether ``variation`` carries :data:`POSE_HELDOUT` (the episode's pose is drawn from the held-out slice)."""
    return (jnp.asarray(variation, jnp.int32) & POSE_HELDOUT) > 0


def prompt(variation) -> jax.Array:
    """Whether ``variation`` carries :data:`PROMPT_ROBOT`."""
    return (jnp.asarray(variation, jnp.int32) & PROMPT_ROBOT) > 0


def following(variation) -> jax.Array:
    """Whether ``variation`` carries :data:`FOLLOWING_PARTNER`."""
    return (jnp.asarray(variation, jnp.int32) & FOLLOWING_PARTNER) > 0


def slice_draw(key: jax.Array, held, inner: tuple[float, float], outer: tuple[float, float],
               symmetric: bool = False) -> jax.Array:
    """A value of a ranged draw: uniform over ``inner`` (the training range), or over ``outer`` (the held-out band
    beyond it) where ``held``. ``symmetric``: the ranges are of the magnitude and the sign is drawn too."""
    k1, k2, k3 = jax.random.split(key, 3)
    a = jax.random.uniform(k1, (), minval=inner[0], maxval=inner[1])
    b = jax.random.uniform(k2, (), minval=outer[0], maxval=outer[1])
    if symmetric:
        b = b * jnp.where(jax.random.bernoulli(k3, 0.5), 1.0, -1.0)
    return jnp.where(held, b, a)


def pace_factor(variation, slow: float, fast: float) -> jax.Array:
    """The human's pace multiplier: ``slow`` / ``fast`` under those variations, else exactly 1."""
    v = jnp.asarray(variation)
    return jnp.where(v == SLOW, slow, jnp.where(v == FAST, fast, 1.0)).astype(jnp.float32)


def pause_schedule(key: jax.Array, variation, num: int, start: tuple[int, int], length: tuple[int, int]):
    """``num`` pauses (start steps in [start), lengths in [length)); lengths are 0 unless ``variation`` is
    PAUSES. Pauses do not overlap in effect (a step is paused if any window covers it)."""
    k1, k2 = jax.random.split(key)
    starts = jnp.sort(jax.random.randint(k1, (num,), *start))
    lens = jax.random.randint(k2, (num,), *length)
    return starts.astype(jnp.int32), jnp.where(jnp.asarray(variation) == PAUSES, lens, 0).astype(jnp.int32)


def paused(starts: jax.Array, lens: jax.Array, t: jax.Array) -> jax.Array:
    """Whether env step ``t`` falls in one of the pause windows."""
    return jnp.any((t >= starts) & (t < starts + lens))


__all__ = ["VARIATIONS", "FOLLOWING_PARTNER", "POSE_HELDOUT", "PROMPT_ROBOT", "HELD_OUT", "human_variation", "held_out",
           "POSE_AXES", "pose_slice", "slice_name", "slice_names", "held_axes", "band_draw", "held_out_sets",
           "is_held_out_set",
           "following", "prompt",
           "slice_draw", "NONE", "SLOW", "FAST", "PAUSES", "DETOUR", "NOISE", "CHANGE_OF_MIND",
           "variation_id", "pace_factor", "pause_schedule", "paused"]
