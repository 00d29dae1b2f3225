"""programs.stored: a jitted function whose traced program is kept on disk and loaded by a later process."""
from __future__ import annotations

import re

import flax.struct
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cogail_jax.runtime import programs


@flax.struct.dataclass
class Box:
    w: jax.Array
    b: jax.Array
    name: str = flax.struct.field(pytree_node=False, default="box")


def make(calls: list, scale: float = 2.0):
    """A function that records each trace in ``calls`` and closes over ``scale`` (a constant of its program)."""

    def fn(box, x):
        calls.append(1)
        y = jnp.tanh(x @ box.w + box.b) * scale
        return box.replace(b=box.b + y.sum(0)), {"y": y, "n": jnp.sum(x > 0)}

    return fn


@pytest.fixture
def folder(tmp_path, monkeypatch):
    monkeypatch.setattr(programs, "program_dir", lambda: tmp_path)
    return tmp_path


def args(n=5):
    k1, k2 = jax.random.split(jax.random.PRNGKey(0))
    return Box(jax.random.normal(k1, (3, 4)), jnp.zeros(4)), jax.random.normal(k2, (n, 3))


def assert_same(a, b):
    assert jax.tree.structure(a) == jax.tree.structure(b)
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_stored_program_matches_jit_and_is_loaded_without_tracing(folder):
    calls = []
    ref = jax.jit(make([]))(*args())
    first = programs.stored(make(calls), "f", key=("cfg", 2.0), donate_argnums=(0,))
    assert_same(first(*args()), ref)
    assert first.traces == 1 and len(calls) == 1 and len(list(folder.glob(f"f-*{programs.SUFFIX}"))) == 1
    first(*args())  # the same shapes: the same program, not traced again
    assert first.traces == 1 and len(calls) == 1

    later = programs.stored(make(calls), "f", key=("cfg", 2.0))  # as a later process: loads the kept program
    assert_same(later(*args()), ref)
    assert later.traces == 0 and len(calls) == 1
    shapes = later.eval_shape(*args())
    assert jax.tree.structure(shapes) == jax.tree.structure(ref) and shapes[1]["y"].shape == (5, 4)
    assert later.lower(*jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype), args())).compile()
    assert len(calls) == 1


def test_another_key_or_shape_is_traced_again(folder):
    calls = []
    programs.stored(make(calls), "f", key=1)(*args())
    other = programs.stored(make(calls, scale=3.0), "f", key=2)  # what it closes over changed: so did its key
    np.testing.assert_allclose(other(*args())[1]["y"], jax.jit(make([], 3.0))(*args())[1]["y"], rtol=1e-6)
    assert other.traces == 1 and len(calls) == 2
    other(*args(n=7))
    assert other.traces == 2 and len(calls) == 3
    assert len(list(folder.glob(f"*{programs.SUFFIX}"))) == 3


def test_unreadable_program_file_is_traced_again(folder):
    calls = []
    ref = programs.stored(make(calls), "f", key=0)(*args())
    (path,) = folder.glob(f"*{programs.SUFFIX}")
    path.write_bytes(b"not a program")
    again = programs.stored(make(calls), "f", key=0)
    assert_same(again(*args()), ref)
    assert again.traces == 1 and len(calls) == 2
    assert_same(programs.stored(make(calls), "f", key=0)(*args()), ref)  # rewritten whole: loaded, not traced
    assert len(calls) == 2


def test_no_folder_traces_in_every_process(monkeypatch):
    monkeypatch.setattr(programs, "program_dir", lambda: None)
    calls = []
    for _ in range(2):
        out = programs.stored(make(calls), "f", key=0)(*args())
    assert len(calls) == 2 and out[1]["y"].shape == (5, 4)


def test_function_that_cannot_be_exported_runs_as_jit(folder):
    def fn(x):  # a host callback cannot be serialised
        return jax.pure_callback(lambda a: np.asarray(a) * 2, jax.ShapeDtypeStruct(x.shape, x.dtype), x) + 1

    f = programs.stored(fn, "cb", key=0)
    np.testing.assert_array_equal(f(jnp.arange(3.0)), [1.0, 3.0, 5.0])
    assert f.eval_shape(jnp.arange(3.0)).shape == (3,) and not list(folder.glob("*"))


def test_digest_is_by_value_not_identity():
    """Treedefs whose static data are objects (MJX's contact data holds array wrappers) digest by value."""

    class Wrap:
        __slots__ = ("array",)

        def __init__(self, a):
            self.array = a

    assert programs.digest(Wrap(np.arange(3))) == programs.digest(Wrap(np.arange(3)))
    assert programs.digest(Wrap(np.arange(3))) != programs.digest(Wrap(np.arange(4)))
    assert programs.digest(jax.tree.structure(args())) == programs.digest(jax.tree.structure(args()))
    assert programs.digest(jax.tree.structure(args())) != programs.digest(jax.tree.structure(args()[0]))
    assert programs.digest({"a": 1.0}) != programs.digest({"a": 1})


# ------------------------------------------------------------------ programs kept under config.program_key
ZERO_OFF = ("bc_coef", "entropy_coef", "gp_coef", "lambda_z", "diversity_coef")  # 0 switches a term off


def _update_fields(cfg, zero: bool) -> dict:
    """Other values of every ``UPDATE_ONLY`` field: with ``zero`` the terms that 0 switches off are off."""
    from cogail_jax.algo.config import UPDATE_ONLY

    out = {}
    for name in UPDATE_ONLY:
        v = getattr(cfg, name)
        if isinstance(v, bool):
            out[name] = not v
        elif isinstance(v, int):
            out[name] = 2 * v if v else 1
        else:
            out[name] = 0.0 if zero and name in ZERO_OFF else 1.5 * v + 0.125
    return out


def _program_texts(cfg, monkeypatch) -> dict[str, list[str]]:
    """The StableHLO of the programs that do not train (the initial state, BC, the checkpoints' evaluation, the
    extra sets' replay, co-play), traced for ``cfg``, by name."""
    from cogail_jax.apps import eval_runner, runs
    from cogail_jax.eval import coplay, rollouts

    made = []
    init = programs.Stored.__init__

    def record(self, *a, **k):
        init(self, *a, **k)
        made.append(self)

    monkeypatch.setattr(programs.Stored, "__init__", record)
    monkeypatch.setattr(programs, "program_dir", lambda: None)  # trace every program: nothing loaded
    s = runs.build(cfg)
    state = s.init.abstract(cfg.seeds, s.expert)  # traces init and BC
    struct = eval_runner._eval_struct(state)
    stacked = jax.tree.map(lambda x: jax.ShapeDtypeStruct((1,) + x.shape, x.dtype), struct)
    held, _ = rollouts.stack_sets({"test": s.heldout, "validation": s.validation}, steps=s.env.max_episode_steps)
    rollouts.make_eval_fn(s.cfg, s.env, s.nets).lower(stacked["params"], stacked["norm"], held)
    rollouts.make_replay_fn(s.cfg, s.env, s.nets).lower(struct["params"], struct["norm"], s.heldout)
    p = coplay.prepare(s, episodes=2, proxy_steps=1)
    p.run.lower(struct["params"], struct["norm"], p.proxy, p.batch)
    monkeypatch.undo()
    texts = {}
    for st in made:
        for prog in st._programs.values():
            texts.setdefault(st.name, []).append(_without_locations(prog.exp.mlir_module()))
    return texts


def _without_locations(text: str) -> str:
    """A module's text without its source locations (they name the caller's lines)."""
    text = "\n".join(line for line in text.splitlines() if not line.startswith("#loc"))
    return re.sub(r" loc\((#loc\d*|unknown)\)", "", text)


def test_update_only_fields_leave_the_other_programs_unchanged(tiny_cfg, monkeypatch):
    """A run that changes only the training update's hyperparameters (config.UPDATE_ONLY) loads the initial state's,
    BC's and the evaluation's kept programs: each of those programs must be the same for every value of them (else
    a program kept for one value would run for another). A field one of them reads (code_noise: the initial
    state's codes) changes it."""
    base = tiny_cfg.replace(bc_steps=2, policy_ema=0.5)
    ref = _program_texts(base, monkeypatch)
    assert set(ref) == {"init", "bc", "evaluate", "replay", "coplay"}
    for zero in (True, False):
        assert _program_texts(base.replace(**_update_fields(base, zero)), monkeypatch) == ref, zero
    control = _program_texts(base.replace(code_noise=0.3), monkeypatch)
    assert control["init"] != ref["init"] and control["bc"] == ref["bc"]
