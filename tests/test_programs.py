"""programs.stored: a jitted function whose traced program is kept on disk and loaded by a later process."""
from __future__ import annotations

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
    assert programs.stored(make(calls), "f", key=0)(*args()) is not None and len(calls) == 2  # rewritten whole


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
