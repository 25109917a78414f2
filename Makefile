# Set-up is a stamp file: the venv is (re)built only when pyproject.toml or constraints.txt change,
# so a second `make test` spends seconds on set-up.
PY      ?= python3
VENV    := .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.arcsem-installed
EXT     := $(VENV)/.arcsem-ext
CPP     := $(wildcard backbones/gaussians/cpp/*.cpp backbones/gaussians/cpp/*.h losses/cpp/*.cpp arcsem/mesh/cpp/*.cpp)
PLX     := $(VENV)/.arcsem-ext-plenoxels
PLX_CPP := $(wildcard backbones/plenoxels/cpp/*.cpp backbones/plenoxels/cpp/*.h)
JOBS    ?= 2
export PIP_DISABLE_PIP_VERSION_CHECK=1

.PHONY: setup demo test lint clean-venv browser slurm

setup: $(EXT) $(PLX)

$(STAMP): pyproject.toml constraints.txt examples/mip_splatting/pyproject.toml
	@test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q -c constraints.txt -e ".[test]" -e examples/mip_splatting
	@touch $(STAMP)

# JIT-build the fused C++ kernels once (a minute or so each); failure is not fatal: the PyTorch path is used.
# The demo's (Gaussian rasterisers, losses, TSDF fusion), then Plenoxels' marcher for setup and the tests.
$(EXT): $(STAMP) $(CPP)
	-$(BIN)/python -m arcsem.backbones.gaussians.fused
	-$(BIN)/python -m arcsem.losses.fused
	-$(BIN)/python -m arcsem.mesh.fused
	@touch $(EXT)

$(PLX): $(STAMP) $(PLX_CPP)
	-$(BIN)/python -m arcsem.backbones.plenoxels.fused
	@touch $(PLX)

demo: $(EXT)
	$(BIN)/arcsem experiment=demo

# Headless Chromium for the page tests (viewer, report): Debian's package, installed when missing and
# apt runs as root (CI); elsewhere those tests are skipped and say why.
browser:
	@command -v chromium >/dev/null 2>&1 || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1 && \
	  echo "installing chromium (apt) for the browser tests" && apt-get update -qq >/dev/null && \
	  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null; } || \
	  echo "chromium not installed: the browser tests will be skipped (apt-get install chromium)"

# A single-node SLURM for the `slurm` tests (tests/slurm/cluster.sh starts and stops it): Debian's slurmctld,
# slurmd, slurm-client and slurmdbd (packages of slurm-wlm), munge, and MariaDB for slurmdbd's accounting (sacct,
# which submitit polls), installed like Chromium; elsewhere those tests are skipped and say why.
SLURM_PKGS := slurmctld slurmd slurm-client slurmdbd munge mariadb-server
slurm:
	@( for exe in slurmctld slurmd slurmdbd sbatch munged mariadbd; do command -v $$exe || exit 1; done ) >/dev/null 2>&1 || \
	  { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1 && \
	  echo "installing slurm, munge and mariadb (apt) for the slurm tests" && apt-get update -qq >/dev/null && \
	  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends $(SLURM_PKGS) >/dev/null; } || \
	  echo "slurm not installed: the slurm tests will be skipped (apt-get install $(SLURM_PKGS))"

# ruff (pinned in constraints.txt, part of the test extra) checks the whole tree before any test runs
lint: $(STAMP)
	$(BIN)/ruff check .

test: lint $(EXT) $(PLX) browser slurm
	$(BIN)/python -m pytest -q -rs -n $(JOBS) --dist loadgroup

clean-venv:
	rm -rf $(VENV)
