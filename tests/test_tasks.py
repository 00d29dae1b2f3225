"""The task API: the env contract over every registered task, the registry, and the package's layout rules (no
module outside a task's package names a built-in task; no import circle)."""
from __future__ import annotations

import ast
import io
import sys
import tokenize
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import cogail_envs
from cogail_envs import Task, Team, UnknownTaskError, builtin_task_names, get_task

ROOT = Path(__file__).parents[1]
EXAMPLE = "examples.table_carry:TASK"
TASKS = [*builtin_task_names(), *([EXAMPLE] if (ROOT / "examples" / "table_carry").exists() else [])]


@pytest.fixture(scope="module", params=TASKS)
def contract(request):
    """One task's env and its two programs, ``jax.jit(env.reset_from)`` and ``jax.jit(env.step)`` (the same
    programs as the task's own tests compile: found in the suite's compilation cache): reset from a sampled init
    twice (reset_from reproduces it), one step of zero action, and one from a state one step before the limit."""
    monkey = pytest.MonkeyPatch()
    monkey.chdir(ROOT)  # examples/ importable as from the repository root
    task = get_task(request.param)
    env = task.make_env()
    reset_from, step = jax.jit(env.reset_from), jax.jit(env.step)
    init = env.sample_init(jax.random.PRNGKey(0))
    # reset(key) starts where reset_from(its init) does: replay restarts a recorded episode from its init
    s0, s0b = reset_from(init), jax.jit(env.reset)(jax.random.PRNGKey(0))
    other = reset_from(env.sample_init(jax.random.PRNGKey(2)))
    a = jnp.zeros(env.action_size)
    s1 = step(s0, a)
    late = step(s0.replace(info={**s0.info, "t": s0.info["t"] + env.max_episode_steps - 1}), a)
    # a checkpoint's env state (env.checkpoint_state) steps to the same bits as the state it was made from
    acts = jax.random.uniform(jax.random.PRNGKey(1), (3, env.action_size), minval=-1, maxval=1)
    ref, got = s1, env.checkpoint_state(s1)
    for x in acts:
        ref, got = step(ref, x), step(got, x)
    out = jax.device_get((init, s0, (s0b, other), s1, late, jax.jit(env.classify_strategy)(s1.metrics), (ref, got)))
    yield task, env, out
    monkey.undo()


def test_env_contract_shapes_and_action_split(contract):
    task, env, (init, s0, _, s1, _, _, _) = contract
    assert env.name == task.name and env.action_size == env.human_action_size + env.robot_action_size
    assert env.human_action_size > 0 and env.robot_action_size > 0 and env.num_strategies == len(env.strategy_names)
    assert s0.obs.shape == (env.observation_size,) and s0.obs.dtype == np.float32 and np.all(np.isfinite(s0.obs))
    assert init.shape == (env.init_size,)
    assert s1.obs.shape == s0.obs.shape and np.all(np.isfinite(s1.obs)) and np.shape(s1.reward) == ()
    assert "success" in s0.metrics and "t" in s0.info and "truncation" in s0.info
    assert jax.tree.structure(s0) == jax.tree.structure(s1)  # step keeps reset's state layout (a scan needs it)
    a = np.arange(env.action_size, dtype=np.float32)
    h, r = env.split_action(a)
    assert h.shape == (env.human_action_size,) and r.shape == (env.robot_action_size,)


def test_env_contract_checkpoint_state_steps_to_the_same_bits(contract):
    _, env, (*_, (ref, got)) = contract
    for x, y in zip(jax.tree.leaves(ref), jax.tree.leaves(got)):
        np.testing.assert_array_equal(x, y)


def test_env_contract_reset_from_reproduces_the_start(contract):
    """reset(key) and reset_from(the init it samples) start in the same state (two programs: equal to float32
    round-off), and another init starts elsewhere (reset_from reads its init)."""
    _, _, (_, s0, (s0b, other), *_) = contract
    for x, y in zip(jax.tree.leaves(s0), jax.tree.leaves(s0b)):
        np.testing.assert_allclose(x, y, rtol=1e-5, atol=1e-6)
    assert not np.allclose(s0.obs, other.obs)


def test_env_contract_time_limit_is_a_truncation(contract):
    """``info["truncation"]`` is 1 when the time limit (not success or failure) ended the episode, 0 before."""
    _, env, (_, s0, _, s1, late, _, _) = contract
    assert int(s1.info["t"]) == 1 and float(s1.done) == 0.0 and float(s1.info["truncation"]) == 0.0
    assert int(late.info["t"]) == env.max_episode_steps
    assert float(late.done) == 1.0 and float(late.info["truncation"]) == 1.0 - float(late.metrics["success"])


def test_env_contract_strategy_classification(contract):
    *_, (_, _, _, s1, _, sid, _) = contract
    assert np.asarray(sid).dtype == np.int32 and np.shape(sid) == ()
    assert float(s1.metrics["success"]) == 0.0 and int(sid) == 0  # an episode that has not succeeded: no strategy


def test_env_contract_render_and_human_position(contract):
    task, env, (_, s0, *_) = contract
    for cam in task.cameras or (None,):
        img = env.render(s0, width=64, height=48, camera=cam) if cam else env.render(s0, width=64, height=48)
        assert img.ndim == 3 and img.shape[2] == 3 and img.dtype == np.uint8 and img.max() > 0
    assert np.asarray(env.human_position(s0)).ndim == 1


def test_render_without_opengl_draws_the_scene(contract, monkeypatch):
    """With no OpenGL, an MJX task's frames are the numpy top + side projection: the boxes in their colours, and a
    scene that moved draws differently."""
    from cogail_envs.mjx_common import FrameRenderer

    task, env, (_, s0, _, _, late, _, _) = contract
    if not hasattr(env, "mj_model"):
        pytest.skip("not rendered by MuJoCo")

    def no_gl(self, *a):
        raise RuntimeError("no OpenGL")

    monkeypatch.setattr(FrameRenderer, "_get", no_gl)
    cam = (task.cameras or (None,))[0]
    a, b = (env.render(s, width=200, height=150, camera=cam) for s in (s0, late))
    assert a.shape == (150, 200, 3) and a.dtype == np.uint8
    assert len(np.unique(a.reshape(-1, 3), axis=0)) >= 4  # background, panels, divider and coloured boxes
    assert not np.array_equal(a, b)


def test_task_settings_resolve(contract):
    """The task's own settings are a valid config, and its splits are what the data step reads."""
    from cogail_jax.algo.config import resolve

    task, env, _ = contract
    cfg = resolve(task.name if task.name in builtin_task_names() else EXAMPLE)
    own = {k: v for k, v in task.default_config().items() if k not in ("task", "budgets")}
    norm = lambda v: tuple(v) if isinstance(v, (list, tuple)) else v  # noqa: E731
    assert own and all(norm(getattr(cfg, k)) == norm(v) for k, v in own.items()), own
    assert all(task.split_size(s) > 0 for s in ("train", "validation", "test"))
    assert task.team is None or isinstance(task.team, Team)


# --------------------------------------------------------------------------------------------- the registry
def test_registry_names_and_errors(tmp_path, monkeypatch):
    assert set(builtin_task_names()) >= {"fetchq", "handover", "seqmanip"}
    with pytest.raises(UnknownTaskError, match="unknown task 'nope'"):
        get_task("nope")
    with pytest.raises(UnknownTaskError, match="cannot be imported"):
        get_task("no_such_pkg.mod:TASK")
    (tmp_path / "my_tasks.py").write_text(
        "from cogail_envs import Task, get_task\n"
        "base = get_task('fetchq')\n"
        "TASK = Task(name='fetchq_copy', env=lambda **kw: None)\n"
        "NOT_A_TASK = 3\n")
    monkeypatch.chdir(tmp_path)
    with pytest.raises(UnknownTaskError, match="not a cogail_envs.Task"):
        get_task("my_tasks:NOT_A_TASK")
    with pytest.raises(UnknownTaskError, match="has no attribute 'MISSING'"):
        get_task("my_tasks:MISSING")
    task = get_task(str(tmp_path / "my_tasks.py") + ":TASK")  # a file path works too
    assert get_task(str(ROOT / "examples" / "table_carry") + ":TASK").name == "table_carry"  # and a package's folder
    assert task.name == "fetchq_copy" and get_task("fetchq_copy") is task
    with pytest.raises(UnknownTaskError, match="registered already"):
        cogail_envs.register_task(Task(name="fetchq_copy", env=lambda **kw: None))


def test_a_task_from_an_entry_point(tmp_path, monkeypatch):
    """An installed distribution declares its tasks in the `cogail.tasks` entry-point group."""
    (tmp_path / "ep_tasks_mod.py").write_text(
        "from cogail_envs import Task, get_task\n"
        "def make():\n"
        "    return Task(name='ep_task', env=get_task('fetchq').env)\n")
    dist = tmp_path / "ep_tasks-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: ep-tasks\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[cogail.tasks]\nep_task = ep_tasks_mod:make\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert "ep_task" in cogail_envs.task_names()
    assert get_task("ep_task").name == "ep_task"


def test_a_task_without_a_team_asks_for_files():
    from cogail_jax.algo.config import TrainConfig
    from cogail_jax.data import io, sets

    fq = get_task("fetchq")
    cogail_envs.register_task(cogail_envs.registry.replace(fq, name="fetchq_no_team", team=None), replace=True)
    cfg = TrainConfig(task="fetchq_no_team")
    with pytest.raises(io.DatasetError, match="no scripted team.*--demos"):
        sets.split_path(cfg, sets.TRAIN)
    assert sets.robustness_paths(cfg) == {}


# --------------------------------------------------------------------------------------------- layout rules
def _code_tokens(path: Path):
    """Identifiers and string literals of a module, docstrings and comments left out."""
    src = path.read_text()
    docstrings = set()
    for node in ast.walk(ast.parse(src)):
        if isinstance(node, (ast.Module, ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) and isinstance(first.value.value, str):
                docstrings.add(first.lineno)
    for tok in tokenize.generate_tokens(io.StringIO(src).readline):
        if tok.type == tokenize.NAME or (tok.type == tokenize.STRING and tok.start[0] not in docstrings):
            yield tok


def test_no_module_outside_a_task_package_names_a_built_in_task():
    import re

    names = builtin_task_names()
    pattern = re.compile(r"\b(" + "|".join(names) + r")\b")
    files = [*(ROOT / "src").rglob("*.py"), *(ROOT / "src").rglob("*.html"),
             *(p for p in (ROOT / "envs").rglob("*.py") if p.parent.name not in names)]
    offenders = []
    for f in files:
        if f.suffix == ".html":
            offenders += [f"{f}: {m.group(0)}" for m in pattern.finditer(f.read_text())]
            continue
        offenders += [f"{f.relative_to(ROOT)}:{t.start[0]}: {t.string[:60]}" for t in _code_tokens(f)
                      if pattern.search(t.string)]
    assert not offenders, "\n".join(offenders)


def _imports(path: Path, package: str) -> set[str]:
    """The modules of the installed packages that ``path`` imports (absolute and relative), as dotted names."""
    tree = ast.parse(path.read_text())
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            out.add(mod)
            out |= {f"{mod}.{a.name}" for a in node.names}
    return {m for m in out if m.split(".")[0] in ("cogail_jax", "cogail_envs")}


def test_no_import_circle():
    modules = {}
    for root, pkg in ((ROOT / "src" / "cogail_jax", "cogail_jax"), (ROOT / "envs", "cogail_envs")):
        for f in root.rglob("*.py"):
            rel = f.relative_to(root).with_suffix("")
            parts = [pkg, *rel.parts]
            if parts[-1] == "__init__":
                parts = parts[:-1]
            name = ".".join(parts)
            modules[name] = (f, name if f.name == "__init__.py" else ".".join(parts[:-1]))
    graph = {m: {i for i in _imports(f, pkg) if i in modules and i != m} for m, (f, pkg) in modules.items()}
    for m in list(graph):  # a module's import of its own package's __init__ is not an edge back (Python allows it)
        graph[m] = {i for i in graph[m] if not m.startswith(i + ".")}
    state, stack, cycles = {}, [], []

    def visit(m):
        state[m] = 1
        stack.append(m)
        for n in graph[m]:
            if state.get(n) == 1:
                cycles.append(stack[stack.index(n):] + [n])
            elif n not in state:
                visit(n)
        stack.pop()
        state[m] = 2

    sys.setrecursionlimit(10_000)
    for m in sorted(graph):
        if m not in state:
            visit(m)
    assert not cycles, "import circles:\n" + "\n".join(" -> ".join(c) for c in cycles)
