# Two commands for a new user: `make run` (set up, then the main job) and `make test`.
PY      ?= python3
VENV    ?= .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.installed
OUT     ?= out

.PHONY: run test setup bench clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q torch==2.13.0 || $(BIN)/python -m pip install -q "torch>=2.4,<2.15"
	$(BIN)/python -m pip install -q -e ".[test]"
	touch $(STAMP)

# the tests also exercise the SUMO and highway-env backends and the SB3 adapter (optional extras for users)
$(VENV)/.extras: $(STAMP)
	$(BIN)/python -m pip install -q -e ".[test,sumo,highway-env,play,ray,sb3,rss]"
	touch $(VENV)/.extras

setup: $(STAMP)

run: $(STAMP)
	$(BIN)/highway-srl demo --out $(OUT)

# test workers (pytest-xdist): one per core, at most 4 (a core count seen through a container's CPU quota
# can be the host's); each test file runs on one worker, so a file's shared fixture (a study, a trained run)
# is built once. `make test TEST_WORKERS=1` runs them in one process.
TEST_WORKERS ?= $(shell n=$$(nproc 2>/dev/null || echo 1); [ $$n -gt 4 ] && n=4; echo $$n)

test: $(VENV)/.extras
	$(BIN)/python -m pytest -n $(TEST_WORKERS) --dist loadfile

bench: $(STAMP)
	$(BIN)/highway-srl bench sim --scenario two-lane --traffic C --envs 4096 --steps 200

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache
