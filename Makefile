# cogail-jax. `make train` and `make test` set everything up themselves on a fresh clone.
SHELL := /bin/bash
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
TASK ?= fetchq
METHOD ?= cogail
SEEDS ?= 300,400,500
BUDGET ?= paper
RUN ?= runs/$(TASK)-$(METHOD)-$(BUDGET)
EXTRA ?=

.PHONY: install browser train eval test demos video bench first-run clean help paper paper-check paper-compare

help:
	@echo "make train [TASK=fetchq|handover|seqmanip|overcooked|overcooked_KITCHEN|module:TASK] [METHOD=cogail|ma_infogail|ma_gail|bc_gail|bc_single|diayn|ppo_bc|ppo_sp]"
	@echo "           [SEEDS=300,400,500] [BUDGET=paper|quick|2x] [RUN=dir] [EXTRA='--set FIELD=VALUE ...']"
	@echo "make eval RUN=dir | make test | make demos TASK=... (the run's datasets) | make video RUN=dir | make bench"
	@echo "make first-run [TASKS=fetchq] (cold, warm and new-config make train, timed; TASKS=fetchq,handover,seqmanip)"
	@echo "make paper [TASKS=fetchq|overcooked (its five kitchens)] [METHODS=...] [MIXES=uniform,D1,D2] [GPUS=all] [JOBS_PER_GPU=1] [TASK_JOBS='handover=2 ...'] [SHARD=i/n]"
	@echo "make paper-check | make paper-compare | make install [CPU=1] [DRY_RUN=1] | make clean (deletes runs/)"

# overcooked-ai 1.1.0 only for the Overcooked trials it ships (Carroll et al. 2019), without the GUI and notebook
# packages it declares (gym, pygame, ipython, ipywidgets): the task reads its data files, never imports it.
# The packages go in with uv (the same versions as pip in a fifth of the time); where uv cannot install them
# (it reads UV_INDEX_URL, not pip's configuration), pip does.
UV_VERSION := 0.13.9
$(BIN)/.installed: pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	@deps() { $$1 -e '.[test]' && $$1 --no-deps overcooked-ai==1.1.0; }; \
	if $(BIN)/python -m pip install -q uv==$(UV_VERSION) && deps "$(BIN)/uv pip install -q --python $(BIN)/python"; then :; \
	else echo "uv could not install the packages: installing them with pip"; deps "$(BIN)/python -m pip install -q"; fi
	touch $@

# The project, then the JAX build for this machine (tools/install_jax.py: the CUDA build matching the driver
# when nvidia-smi finds an NVIDIA GPU, else the CPU build; CPU=1 forces the CPU build; a build already in place
# is kept). DRY_RUN=1 only prints the pip command.
ifeq ($(DRY_RUN),1)
install:
	@$(PYTHON) tools/install_jax.py --dry-run --python $(BIN)/python
else
install: $(BIN)/.installed browser
	@$(BIN)/python tools/install_jax.py
endif

# Headless Chromium + chromedriver (Debian packages) for the browser tests of `cogail play`; installed when
# missing (with sudo unless root; the package lists are refreshed only if the install fails without). A failure
# only warns, so `make train` never depends on it.
browser:
	@if command -v chromium >/dev/null && command -v chromedriver >/dev/null; then :; \
	elif command -v apt-get >/dev/null; then \
	  SUDO=$$([ "$$(id -u)" = 0 ] || echo sudo); \
	  APT="$$SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver"; \
	  $$APT 2>/dev/null || { $$SUDO apt-get update -qq && $$APT; } \
	    || echo "warning: could not install chromium chromium-driver: tests/test_play.py will fail"; \
	else echo "warning: chromium/chromedriver missing and no apt-get: tests/test_play.py will fail"; fi

# Makes the run's datasets (kept in data/ and reused), trains with the task's settings under BUDGET, then evaluates
# every checkpoint. Re-running the same command resumes an interrupted run from its last checkpoint (other TASK,
# METHOD, SEEDS, BUDGET or EXTRA settings for a RUN that has trained stop with the fields that differ).
# TASK may also be your own task, e.g. TASK=examples.table_carry:TASK (docs/tasks.md).
CONFIG_ARGS = --task $(TASK) --budget $(BUDGET) --method $(METHOD) --seeds $(SEEDS) $(EXTRA)
train: install
	$(BIN)/cogail data $(CONFIG_ARGS)
	$(BIN)/cogail train $(CONFIG_ARGS) --run $(RUN) --eval $(if $(wildcard $(RUN)/config.json),--resume,)

eval: install
	$(BIN)/cogail eval --run $(RUN)

demos: install
	$(BIN)/cogail data $(CONFIG_ARGS)

video: install
	$(BIN)/cogail video $(if $(wildcard $(RUN)/config.json),--run $(RUN),--task $(TASK)) --out $(RUN)/rollouts.gif

# The suite in TEST_WORKERS processes (pytest-xdist), one test file per worker at a time, the heaviest files first
# (tests/conftest.py). TEST_WORKERS=0 runs it in this process.
TEST_WORKERS ?= 2
test: install
	$(BIN)/python -m pytest -q $(if $(filter 0,$(TEST_WORKERS)),,-n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder) \
	  --durations=15 tests

clean:
	rm -rf runs .pytest_cache

# The paper's tables (Table 1 replay, Table 2 interpolation, Fig. 3) for TASKS x METHODS, 3 seeds each; the jobs run
# one per GPU over GPUS (all visible ones by default; JOBS_PER_GPU=K: K side by side on each), the rest queued, each
# task's datasets first; SHARD=i/n runs the i-th of n hosts' share; TASK_JOBS="handover=2 seqmanip=2": at most that
# many of a task's jobs side by side on one GPU.
TASKS ?= fetchq
METHODS ?=
MIXES ?= uniform
GPUS ?= all
JOBS_PER_GPU ?= 1
SHARD ?=
TASK_JOBS ?=
paper: install
	$(BIN)/python experiments/paper.py --tasks $(TASKS) $(if $(METHODS),--methods $(METHODS),) --mixes $(MIXES) --out results/paper \
	  --gpus $(GPUS) --jobs-per-gpu $(JOBS_PER_GPU) $(if $(SHARD),--shard $(SHARD),) \
	  $(foreach c,$(TASK_JOBS),--task-jobs-per-gpu $(c))

# Which rows of the shipped tables were not trained from this checkout's code with the current settings.
paper-check: install
	$(BIN)/python experiments/paper.py --check --out docs/results/paper

# make paper's rows (results/paper) against the shipped tables', figure by figure to the last digit
paper-compare: install
	$(BIN)/python experiments/paper.py --out results/paper --compare docs/results/paper

# The throughput table of TASK, then the seconds per phase (start, demos, bc, compile, train, eval, write) of every
# run under runs/ that has a speed.json (e.g. the `make train` runs of each task).
bench: install
	$(BIN)/cogail data --task $(TASK) --no-robustness
	$(BIN)/cogail bench $(TASK) runs/bench-$(TASK).json
	@runs=$$(ls runs/*/speed.json 2>/dev/null | xargs -r -n1 dirname); \
	if [ -n "$$runs" ]; then $(BIN)/cogail bench --phases $$runs; fi

# What a first `make train` costs, per task in TASKS: cold (fresh compilation cache and data folder), warm, and a
# new config with the datasets on disk; wall times, phases, compilations and run-folder sizes in
# runs/first-run/first_run.md (experiments/first_run.py).
first-run: install
	$(BIN)/python experiments/first_run.py --tasks $(TASKS) --seeds $(SEEDS) --out runs/first-run
