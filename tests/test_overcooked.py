"""Overcooked on JaxMARL: the env's contract (one-hot actions, 400-step truncation, metrics, the init vector),
its fidelity to the people's trials (open-loop replay of a slice, grids and start cells), the recorded splits and
the strategy labels."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

pytest.importorskip("jaxmarl")

from cogail_envs import get_task  # noqa: E402
from cogail_envs.overcooked import VARIANTS, kitchen as kt, report, trials as tr  # noqa: E402
from cogail_envs.overcooked.env import NUM_ACTIONS, Overcooked, one_hot_actions  # noqa: E402


def _has_trials() -> bool:
    try:
        tr.trial_file("train")
        return True
    except FileNotFoundError:
        return False


needs_trials = pytest.mark.skipif(not _has_trials(), reason="pip install --no-deps overcooked-ai==1.1.0")


@pytest.fixture(scope="module")
def env():
    return Overcooked()


@pytest.fixture(scope="module")
def fns(env):
    """The env's jitted programs: reset_from, step, encode(reset_from(init)) over a batch, and a 400-step rollout
    of uniformly random actions from reset(key)."""

    def rollout(key):
        def body(state, k):
            a = jax.nn.one_hot(jax.random.randint(k, (2,), 0, NUM_ACTIONS), NUM_ACTIONS).reshape(-1)
            nxt = env.step(state, a)
            return nxt, (nxt.done, nxt.info["truncation"], nxt.info["t"], nxt.reward)

        k0, k1 = jax.random.split(key)
        return jax.lax.scan(body, env.reset(k0), jax.random.split(k1, env.max_episode_steps))

    round_trip = jax.vmap(lambda i: env.encode(env.reset_from(i)))
    return dict(reset_from=jax.jit(env.reset_from), step=jax.jit(env.step), round_trip=jax.jit(round_trip),
                rollout=jax.jit(rollout))


def _seated(game, seat: int = 0):
    """An env init vector: a game state (kitchen's layout) with the human seated as player ``seat``."""
    return jnp.append(jnp.asarray(game, jnp.float32), float(seat))


def _action(h: int, r: int) -> jnp.ndarray:
    return jnp.asarray(one_hot_actions([h, r]).reshape(-1))


# --------------------------------------------------------------------------------------------- the env
def test_reset_step_shapes_and_one_hot_actions(env, fns):
    assert env.obs_grid == (4, 5, 26) and env.observation_size == 520 and env.action_size == 12
    assert env.human_action_discrete and env.robot_action_discrete and env.score_metric == "soups"
    assert env.init_size == 8 + 2 * 1 + 9 + 1  # cramped room: one pot, nine counter cells, and the human's seat
    s = fns["reset_from"](_seated(kt.start_init(env.geometry, jnp.array([0, 0]))))
    assert s.obs.shape == (520,) and s.obs.dtype == jnp.float32
    np.testing.assert_array_equal(np.asarray(s.obs).reshape(env.obs_grid)[..., 0].nonzero(), ([2], [1]))  # human
    # the human (at (1, 2)) moves right, the robot interacts with nothing; argmax of any vector acts alike
    s1 = fns["step"](s, _action(2, 5))
    s2 = fns["step"](s, jnp.array([0.1, -3, 2.5, 0, 0, 1, 0, 0, 0, 0, 0, 0.7]))
    assert np.asarray(s1.pipeline_state.agent_pos).tolist() == [[2, 2], [3, 1]]
    assert int(s1.pipeline_state.agent_dir_idx[0]) == 2
    for x, y in zip(jax.tree.leaves(s1), jax.tree.leaves(s2)):
        np.testing.assert_array_equal(x, y)
    # a half of zeros (a replayed recording past its end) is stay, not argmax's first action (up)
    s3 = fns["step"](s, jnp.zeros(12).at[6 + 1].set(1.0))  # the human gives nothing, the robot moves down
    s4 = fns["step"](s, _action(4, 1))
    for x, y in zip(jax.tree.leaves(s3), jax.tree.leaves(s4)):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(s1.obs, env._obs(env._game.get_obs(s1.pipeline_state), 0))  # agent_0's view
    assert s1.info["t"].dtype == jnp.int32 and int(s1.info["t"]) == 1
    assert set(s1.metrics) == {"success", "soups", "onions_h", "onions_r", "plates_h", "plates_r", "dished_h",
                               "dished_r", "served_h", "served_r"}
    assert all(v.dtype == jnp.float32 for v in s1.metrics.values())


def test_episodes_end_at_400_steps_as_truncations(fns):
    final, (done, trunc, t, reward) = jax.device_get(fns["rollout"](jax.random.PRNGKey(3)))
    assert np.array_equal(t, np.arange(1, 401)) and t.dtype == np.int32
    assert done[:-1].max() == 0 and done[-1] == 1 and np.array_equal(done, trunc)
    m = final.metrics
    assert np.all(reward % 20 == 0) and reward.sum() == 20 * m["soups"]
    assert m["soups"] == m["served_h"] + m["served_r"] and m["success"] == float(m["soups"] > 0)


def test_start_cells_and_the_jaxmarl_start(env):
    init = np.asarray(env.sample_init(jax.random.PRNGKey(0)))
    assert init[:4].tolist() == [1, 2, 3, 1] and np.all(init[8:-1] == [0, 20, *[0] * 9])
    seats = np.asarray(jax.vmap(env.sample_init)(jax.random.split(jax.random.PRNGKey(1), 64)))[:, -1]
    assert set(seats.tolist()) == {0.0, 1.0}  # the human drawn into either seat
    # start="jaxmarl" starts as JaxMARL's own reset does, state for state
    other = Overcooked(start="jaxmarl")
    assert other.version != env.version
    key = jax.random.PRNGKey(5)
    _, ref = jax.jit(other._game.reset)(key)
    dirs = np.asarray(ref.agent_dir_idx)
    ours = other.reset_from(_seated(kt.start_init(other.geometry, dirs, other.geometry.jaxmarl_start))).pipeline_state
    for name in ("agent_pos", "agent_dir", "agent_dir_idx", "agent_inv", "goal_pos", "pot_pos", "wall_map",
                 "maze_map"):
        a, b = np.asarray(getattr(ours, name)), np.asarray(getattr(ref, name))
        assert a.dtype == b.dtype and np.array_equal(a, b), name


def test_person_features_are_overcooked_ai_s(env):
    """The hand-made features the field's BC models read (features.py), on the cramped room: the human at (1, 2)
    facing left, the robot at (3, 1) facing up; then the human holding an onion beside a pot with one onion."""
    from cogail_envs.overcooked import features

    feat = jax.jit(env.person_features)
    game = np.array(env.sample_init(jax.random.PRNGKey(0)))[:-1]
    game[:6] = [1, 2, 3, 1, 3, 0]  # cells (x0, y0, x1, y1), facings: left, up
    x = np.asarray(feat(env.reset_from(_seated(game)).obs))
    assert x.shape == (features.FEATURES,)
    human, robot, rest = x[:30], x[30:60], x[60:]
    np.testing.assert_array_equal(human[:7], [0, 0, 0, 1, 0, 0, 0])  # facing left, empty-handed
    # nearest onion pile (0, 1), empty pot (2, 0), no pot with onions, cooking or ready, plate pile (1, 3), no loose
    # soup, serving spot (3, 3); the counter it faces is empty; walls below (the plate pile) and to the left
    np.testing.assert_array_equal(human[7:25], [-1, -1, 1, -2, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 2, 1])
    np.testing.assert_array_equal(human[25:], [1, 0, 1, 0, 1])
    np.testing.assert_array_equal(robot[:11], [1, 0, 0, 0, 0, 0, 0, 1, 0, -1, -1])  # the pile beside it, the pot
    np.testing.assert_array_equal(rest, [2, -1, 1, 2])  # the robot from the human; the human's cell
    game[6], game[8] = 1, 1  # the human holds an onion; the pot holds one
    x = np.asarray(feat(env.reset_from(_seated(game)).obs))
    np.testing.assert_array_equal(x[4:13], [1, 0, 0, 0, 0, 0, 0, 1, -2])  # no "nearest onion", no empty pot
    # the robot's view: its own features first
    y = np.asarray(feat(env.reset_from(_seated(game)).obs[np.asarray(env.seat_view)]))
    np.testing.assert_array_equal(y[:30], x[30:60])
    np.testing.assert_array_equal(y[30:60], x[:30])
    np.testing.assert_array_equal(y[60:], [-2, 1, 3, 1])


def test_walking_costs_go_around_counters():
    """Nearest by the floor path to a cell beside the target: around a counter, and never through one."""
    from cogail_envs.overcooked import features

    F, X = kt.FLOOR, kt.COUNTER
    cells = np.array([[F, X, F],
                      [F, X, F],
                      [F, F, F]])
    cost = features.walking_costs(cells)
    assert cost[0, 2] == 5  # (0, 0) to (2, 0): beside it is (2, 1)... reached around the counters' column
    assert cost[0, 1] == 0  # a counter beside the floor cell it starts on
    walled = features.walking_costs(np.array([[F, X, F, F]]))
    assert walled[0, 3] >= features._FAR and walled[2, 3] == 0  # the other side of a counter is out of reach


def test_classify_strategy_thresholds(env):
    def label(oh, orr, dh, dr, sh=None, sr=None, soups=1.0):
        sh = dh if sh is None else sh
        sr = dr if sr is None else sr
        m = {"onions_h": oh, "onions_r": orr, "dished_h": dh, "dished_r": dr, "served_h": sh, "served_r": sr,
             "success": float(soups > 0)}
        return int(env.classify_strategy({k: jnp.float32(v) for k, v in m.items()}))

    assert label(20, 0, 0, 6) == 1  # human cooks, robot serves
    assert label(2, 1, 1, 2) == 1  # exactly 2/3 and 1/3 count
    assert label(0, 15, 5, 0) == 2  # robot cooks, human serves
    assert label(9, 11, 6, 0) == 3  # cooking shared
    assert label(10, 8, 4, 2, 3, 2) == 3  # both shared
    assert label(24, 0, 7, 0) == 4  # human cooks and serves (forced coordination's right-hand cook)
    assert label(3, 15, 0, 4) == 5  # robot cooks and serves
    assert label(0, 0, 0, 3) == 3  # no onion in this episode: cooking is nobody's, so shared
    assert label(20, 0, 0, 6, soups=0) == 0  # nothing delivered
    assert env.strategy_names[0] == "human cooks, robot serves" and env.num_strategies == 5


def test_render_draws_both_agents(env, fns):
    s = fns["reset_from"](_seated(kt.start_init(env.geometry, jnp.array([1, 2]))))
    img = env.render(s, 320, 240)
    assert img.shape == (240, 320, 3) and img.dtype == np.uint8
    px = img.reshape(-1, 3).astype(int)
    for rgb in ((240, 120, 40), (40, 160, 230)):  # orange human, blue robot
        assert np.any(np.all(px == rgb, axis=1))
    assert np.asarray(env.human_position(s)).tolist() == [1.0, 2.0]


def test_tasks_and_variants():
    assert get_task("overcooked").make_env().kitchen == "cramped_room"
    names = {v.name for v in VARIANTS}
    assert names == {f"overcooked_{k}" for k in kt.KITCHENS if k != "cramped_room"}
    task = get_task("overcooked_forced_coordination")
    assert task.team is None and task.recorded is tr.recorded and task.config("quick")["total_steps"] == 256_000
    assert task.split_size("train") == 24 and get_task("overcooked").split_size("test") == 48
    with pytest.raises(ValueError, match="unknown kitchen"):
        Overcooked("kitchen_sink")


# --------------------------------------------------------------------------------------------- the trials
@needs_trials
@pytest.mark.parametrize("kitchen", ["cramped_room", "forced_coordination"])
def test_open_loop_replay_matches_the_recording(kitchen):
    """The first 300 steps of a trial, replayed open loop from its recorded first state: every field of every
    next state (positions, orientations, held items, pots, counters, deliveries) is the recorded one."""
    a = tr.replay_agreement(kitchen, "train", steps=300, trial_index=0)
    assert a["steps"] == 300 and a["first_divergence"] == [-1]
    assert all(a[f] == 300 for f in (*tr.FIELDS, "all")), a


@needs_trials
def test_reset_from_restores_recorded_states(env, fns):
    inits = np.concatenate([t.inits[::3] for t in tr.trials("cramped_room", "train")[:2]])
    assert len(np.unique(inits, axis=0)) > 100
    inits = np.concatenate([inits, (np.arange(len(inits)) % 2)[:, None]], 1).astype(np.float32)  # either seat
    np.testing.assert_array_equal(np.asarray(fns["round_trip"](jnp.asarray(inits))), inits)


@needs_trials
def test_grids_and_start_cells_are_the_trials():
    df = tr._frame(str(tr.trial_file("train")))
    for kitchen, (_, data_name) in kt.KITCHENS.items():
        rows = df[df.layout_name == data_name].sort_values(["workerid_num", "cur_gameloop"])
        k = kt.kitchen_geometry(kitchen)
        assert tr.data_grid(rows.layout.iloc[0]) == tr.kitchen_grid(k), kitchen
        first = tr.data_init(k, tr.parse(rows.state.iloc[0]))
        assert first[:4].reshape(2, 2).tolist() == k.start.tolist(), kitchen


@needs_trials
def test_recorded_splits(env):
    pairs = {s: {t.pair for t in tr.split_trials("cramped_room", s)} for s in tr.SPLITS}
    assert len(pairs["validation"]) >= 2 and len(pairs["train"]) > len(pairs["validation"])
    assert not (pairs["train"] & pairs["validation"] or pairs["train"] & pairs["test"]
                or pairs["validation"] & pairs["test"])
    r = tr.recorded(env, "validation")
    n = len(r["length"])
    assert r["obs"].shape == (n, 400, 520) and r["obs"].dtype == np.float32
    assert set(r["pair"].tolist()) == pairs["validation"] and r["init"].shape == (n, env.init_size)
    for key in ("actions_human", "actions_robot"):
        a = r[key]
        assert a.shape == (n, 400, 6) and a.dtype == np.float32 and np.all(a.sum(-1) == 1) and np.all(a.max(-1) == 1)
    assert np.all((100 <= r["length"]) & (r["length"] <= 400))
    first = jax.vmap(env.reset_from)(jnp.asarray(r["init"])).obs
    np.testing.assert_array_equal(r["obs"][:, 0], np.asarray(first))
    assert np.array_equal(r["strategy"], r["executed"]) and r["strategy"].dtype == np.int32
    assert np.array_equal(r["strategy"], np.asarray(jax.vmap(env.classify_strategy)(r["final_metrics"])))
    # the replayed episodes deliver what the people delivered in each 400-step window
    trial = {t.pair: t for t in tr.split_trials("cramped_room", "validation")}
    seen: dict[int, int] = {}
    for i in range(n):  # each window twice: the human as player 0, then as player 1
        start = 400 * (seen.setdefault(int(r["pair"][i]), 0) // 2)
        seen[int(r["pair"][i])] += 1
        got = trial[int(r["pair"][i])].deliveries[start:start + r["length"][i]].sum()
        assert r["final_metrics"]["soups"][i] == got
    assert r["success"].shape == (n,) and np.all(r["success"] == (r["final_metrics"]["soups"] > 0))
    # docs/overcooked.md's tables (report.py) count each window once, the copy with player 0 as the human
    w = report.window_counts(env, r)
    assert 2 * w["episodes"] == n and 2 * w["steps"] == r["length"].sum() and sum(w["strategies"]) == n // 2
    assert 2 * w["soups"] == r["final_metrics"]["soups"].sum()
    assert r["source"]["file"].endswith("clean_train_trials.pickle") and len(r["source"]["sha256"]) == 64
    assert r["source"]["kitchen"] == "cramped_room" and r["source"]["split"] == "validation"


@needs_trials
def test_each_recorded_window_in_both_seats(env):
    """Each 400-step window comes twice: the human agent as the trial's player 0, then as its player 1; the second
    sees the state as player 1 does (``seat_view``), its agents' actions and jobs swapped."""
    r = tr.recorded(env, "validation")
    perm = np.asarray(env.seat_view)
    a, b = slice(0, None, 2), slice(1, None, 2)
    assert np.all(r["init"][a, -1] == 0) and np.all(r["init"][b, -1] == 1)
    np.testing.assert_array_equal(r["init"][a, :-1], r["init"][b, :-1])
    np.testing.assert_array_equal(r["obs"][b], r["obs"][a][..., perm])
    np.testing.assert_array_equal(r["actions_human"][b], r["actions_robot"][a])
    m = r["final_metrics"]
    for job in ("onions", "plates", "dished", "served"):
        np.testing.assert_array_equal(m[f"{job}_h"][b], m[f"{job}_r"][a])
    mirror = {0: 0, 1: 2, 2: 1, 3: 3, 4: 5, 5: 4}  # who cooks and who serves, swapped
    assert [mirror[int(x)] for x in r["strategy"][a]] == r["strategy"][b].tolist()


@needs_trials
def test_the_normaliser_keeps_planes_the_people_never_lit_small(env):
    """The task's observation floor: a 0/1 plane that no step of the people's trials lit (a start cell and facing
    they never had) reads about 1 when a start lights it, not 1 / 0.01 (the trainer's own default floor)."""
    r = tr.recorded(env, "validation")
    steps = np.arange(r["obs"].shape[1])[None] < r["length"][:, None]
    obs = r["obs"][steps]
    floor = get_task("overcooked").config()["obs_std_floor"]
    mean, std = obs.mean(0), np.maximum(obs.std(0), floor)
    starts = np.asarray(jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(0), 64)).obs)
    unseen = (obs.std(0) == 0) & np.any(starts != obs[0], axis=0)  # constant in the trials, not at some start
    assert unseen.any()  # the starts light planes the people never lit
    assert np.abs((starts - mean) / std).max() <= 2.0
