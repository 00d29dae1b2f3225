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
"""
from __future__ import annotations

import jax
import jax.numpy as jnp

VARIATIONS = ("slow", "fast", "pauses", "detour", "noise", "change_of_mind")
NONE, SLOW, FAST, PAUSES, DETOUR, NOISE, CHANGE_OF_MIND = range(7)
FOLLOWING_PARTNER = 8  # flag bit on a variation id: the scripted robot follows the human's apparent strategy

# salt for the variation's own random draws (fold_in of the team key): the default draws stay as they were
VARIATION_SALT = 7_777


def variation_id(variation: int | str | None) -> int:
    """``None`` / ``"none"`` -> 0, a name of :data:`VARIATIONS` -> its id (1..6), an int -> itself."""
    if variation is None:
        return NONE
    if isinstance(variation, str):
        if variation == "none":
            return NONE
        if variation not in VARIATIONS:
            raise ValueError(f"unknown variation {variation!r}: choose one of {', '.join(VARIATIONS)}")
        return VARIATIONS.index(variation) + 1
    return int(variation)


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


__all__ = ["VARIATIONS", "FOLLOWING_PARTNER", "NONE", "SLOW", "FAST", "PAUSES", "DETOUR", "NOISE", "CHANGE_OF_MIND",
           "variation_id", "pace_factor", "pause_schedule", "paused"]
