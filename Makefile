# sigma: the first two targets are the README's first two commands.
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.sigma-installed
export HF_HUB_OFFLINE ?= 1
export TOKENIZERS_PARALLELISM ?= false

.PHONY: demo test setup lint format bench clean

## demo: the main job, offline, on embedded defaults (sets everything up first)
demo: $(STAMP)
	$(PY) -m pipelines.demo $(ARGS)

## test: lint + the fast test suite (sets everything up first)
test: $(STAMP) lint
	$(PY) -m pytest $(ARGS)

setup: $(STAMP)

$(STAMP): pyproject.toml scripts/setup.sh
	VENV=$(VENV) bash scripts/setup.sh
	@touch $@

lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

format: $(STAMP)
	$(VENV)/bin/ruff check --fix .
	$(VENV)/bin/ruff format .

clean:
	rm -rf $(VENV) outputs .pytest_cache .ruff_cache
