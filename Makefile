# The two set-up commands of the README: `make demo` and `make test`.
# Each creates the virtual env and installs what it needs on first use.
PY      ?= python3
VENV    := .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.installed-stamp
FIELD   ?= field_config/demo_north.yaml
DEMO_OUT ?= demo_out

# The crew console's browser tests drive Debian's Chromium through its chromedriver, and the stream
# camera's tests read a real RTSP stream served by Debian's ffmpeg: installed here when missing
# (apt-get, with sudo when not root); nothing is downloaded by selenium itself.
SUDO    := $(shell [ "$$(id -u)" = 0 ] || echo sudo)

.PHONY: demo test venv clean browser warm

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

venv: $(STAMP)

# the compiled kernels (numba, cached beside their source): compiled once here, not in a run or a test worker
warm: $(STAMP)
	$(BIN)/python -m helicalib.warm

demo: $(STAMP) warm
	$(BIN)/helicalib demo $(FIELD) --out $(DEMO_OUT)

browser:
	@if [ ! -x /usr/bin/chromium ] || [ ! -x /usr/bin/chromedriver ] || [ ! -x /usr/bin/ffmpeg ]; then \
	  echo "installing chromium, chromium-driver and ffmpeg (the console's browser tests, the stream camera's tests)"; \
	  $(SUDO) apt-get update -qq && \
	  DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq chromium chromium-driver ffmpeg >/dev/null; \
	fi

test: $(STAMP) browser warm
	MPLBACKEND=Agg $(BIN)/python -m pytest -q -n 2 --dist loadfile --durations=25

clean:
	rm -rf $(VENV) $(DEMO_OUT) .pytest_cache build src/*.egg-info
