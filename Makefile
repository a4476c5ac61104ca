# Everything a new user needs: `make demo` and `make test` build the virtualenv on first use.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
PKGS   := dbcslam_core dbcslam_ros sim_publisher dbcslam_ros/research

.PHONY: venv test lint typecheck pytest demo experiments bench science clean

$(STAMP): requirements.txt $(foreach p,$(PKGS),$(p)/setup.py)
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --upgrade pip
	$(BIN)/python -m pip install -r requirements.txt
	# compat mode: a path entry, so `python -m pkg` from the repo root finds the real package
	$(BIN)/python -m pip install --no-deps --config-settings editable_mode=compat $(foreach p,$(PKGS),-e $(p))
	# compile the filter's numba kernels into their cache once (~30 s), not in a node's start
	$(BIN)/python -c "from dbcslam_core.rbpf import warm_up_kernels as w; print(f'filter kernels compiled in {w():.1f} s')"
	touch $@

venv: $(STAMP)

lint: venv
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

typecheck: venv
	$(BIN)/mypy

pytest: venv
	$(BIN)/pytest

test: lint typecheck pytest

demo: venv
	$(BIN)/dbcslam demo

experiments: venv
	$(BIN)/python -m dbcslam_research.experiments
	$(BIN)/python -m dbcslam_research.experiments_sim
	$(BIN)/python -m dbcslam_research.readme_results

# the discrepancy benchmark of every scenario (30 + 30 draws each: hours) and the MIT
# full-push NMSE table; `make science MITPUSH=DIR` for another copy of the dataset
MITPUSH ?= ../shared/data/mit-push
SCIENCE := dbcslam_ros/research/results/science
# (edge at 300 scoring particles, gripper and push at 150; then the oracle of each: which
# hidden effects the held-out run resolves at all)
science: venv
	$(BIN)/python -m dbcslam_research.science --scenario edge --out $(SCIENCE)
	$(BIN)/python -m dbcslam_research.science --scenario gripper --particles 150 --out $(SCIENCE)/gripper
	$(BIN)/python -m dbcslam_research.science --scenario push --particles 150 --out $(SCIENCE)/push
	$(BIN)/python -m dbcslam_research.science --scenario edge --oracle --out $(SCIENCE)
	$(BIN)/python -m dbcslam_research.science --scenario gripper --particles 150 --oracle --out $(SCIENCE)/gripper
	$(BIN)/python -m dbcslam_research.science --scenario push --particles 150 --oracle --out $(SCIENCE)/push
	$(BIN)/python -m dbcslam_research.push_nmse $(MITPUSH) --out dbcslam_ros/research/results/push_nmse

bench: venv
	$(BIN)/python -m dbcslam_research.bench
	$(BIN)/python -m dbcslam_research.bench_live --offline
	$(BIN)/python -m dbcslam_research.readme_results

clean:
	rm -rf $(VENV) build ros_ws/build ros_ws/install ros_ws/log .mypy_cache .ruff_cache .pytest_cache
