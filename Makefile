# Two commands do everything on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3.11
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: install demo test bench contracts clean

install: $(STAMP)

# torch goes first, pinned to the CPU wheel on the machine: an unpinned torch pulls a multi-GB CUDA build.
$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet torch==2.13.0
	$(BIN)/pip install --quiet -e ".[dev]"
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/simgen demo --out report/demo
	$(BIN)/simgen build specs/demo.toml --store report/demo/demo.zarr
	$(BIN)/simgen status report/demo/demo.zarr
	$(BIN)/learner train specs/train-demo.toml --fresh
	$(BIN)/learner evaluate report/demo/train/best.pt report/demo/demo.zarr --out report/demo/eval
	# a patient's path with the shipped model, no training (docs/your-heart.md): a mesh as it is, sites by region
	$(BIN)/simgen mesh report/demo/your-heart/heart.vtu --mesh real:tof-biv --nodes 4000
	$(BIN)/simgen simulate report/demo/your-heart/recordings --mesh report/demo/your-heart/heart.vtu \
		--tissue scar-septal-basal --site-region aha-1,aha-6,aha-10,aha-16 --observe electrodes --noise 2
	$(BIN)/learner personalize anatomies --mesh report/demo/your-heart/heart.vtu \
		--observations report/demo/your-heart/recordings/observations.npz --out report/demo/your-heart/heart.pt
	$(BIN)/learner predict report/demo/your-heart/heart.pt --site-region aha-7,apex \
		--out report/demo/your-heart/prediction.npz --vtk report/demo/your-heart/vtk --png report/demo/your-heart/prediction.png
	$(BIN)/simgen simulate report/demo/your-heart/truth --mesh report/demo/your-heart/heart.vtu \
		--tissue scar-septal-basal --site-region aha-7,apex --vtk report/demo/your-heart/truth/vtk
	$(BIN)/learner compare report/demo/your-heart/prediction.npz report/demo/your-heart/truth/simulation.npz \
		--png report/demo/your-heart/compare.png --json report/demo/your-heart/compare.json
	# the same heart from endocardial activation-time maps, as a mapping system exports them
	$(BIN)/simgen simulate report/demo/your-heart/maps --mesh report/demo/your-heart/heart.vtu \
		--tissue scar-septal-basal --site-region aha-1,aha-6,aha-10,aha-16 --observe endocardium --record activation --noise 3
	$(BIN)/learner personalize anatomies --mesh report/demo/your-heart/heart.vtu \
		--observations report/demo/your-heart/maps/observations.npz --out report/demo/your-heart/maps.pt
	$(BIN)/learner predict report/demo/your-heart/maps.pt --site-region aha-7,apex --out report/demo/your-heart/maps.npz
	$(BIN)/learner compare report/demo/your-heart/maps.npz report/demo/your-heart/truth/simulation.npz
	# the same heart from the 12-lead ECGs of the same pacings
	$(BIN)/simgen simulate report/demo/your-heart/ecg --mesh report/demo/your-heart/heart.vtu \
		--tissue scar-septal-basal --site-region aha-1,aha-6,aha-10,aha-16 --observe ecg --noise 0.02
	$(BIN)/learner personalize anatomies --mesh report/demo/your-heart/heart.vtu \
		--observations report/demo/your-heart/ecg/observations.npz --out report/demo/your-heart/ecg.pt
	$(BIN)/learner predict report/demo/your-heart/ecg.pt --site-region aha-7,apex --out report/demo/your-heart/ecg.npz
	$(BIN)/learner compare report/demo/your-heart/ecg.npz report/demo/your-heart/truth/simulation.npz

test: $(STAMP)
	$(BIN)/pytest -q

bench: $(STAMP)
	$(BIN)/python -m bench.solver --out report/bench
	$(BIN)/python -m bench.conduction --out report/bench
	$(BIN)/python -m bench.convergence --out report/bench
	$(BIN)/python -m bench.real_hearts --out report/bench
	$(BIN)/python -m bench.build --out report/bench
	$(BIN)/python -m bench.store_read --out report/bench
	$(BIN)/python -m bench.surrogate --out report/bench
	$(BIN)/python -m bench.resolution --out report/bench
	$(BIN)/python -m bench.predict --out report/bench
	$(BIN)/python -m bench.scaling --out report/bench
	$(BIN)/python -m bench.anisotropy --out report/bench
	$(BIN)/python -m bench.fill --out report/bench
	$(BIN)/python -m bench.ecg --out report/bench

# The private zarr and numba APIs (shared/zarr_format.py, simgen/solver/numba_internals.py) against the newest
# releases on PyPI, in a venv of their own: each failing check names the API that changed.
contracts:
	$(PYTHON) -m venv .contracts
	.contracts/bin/pip install --quiet --upgrade pip
	.contracts/bin/pip install --quiet torch==2.13.0
	.contracts/bin/pip install --quiet -e ".[dev]"
	.contracts/bin/pip install --quiet --upgrade --no-deps zarr numba llvmlite
	.contracts/bin/python -c "import zarr, numba; print('zarr', zarr.__version__, 'numba', numba.__version__)"
	.contracts/bin/pytest -q tests/contracts

clean:
	rm -rf $(VENV) .contracts report .pytest_cache
