# Two commands do all the set-up: `make demo` renders the report's room, `make test` runs the tests.
VENV   ?= .venv
PYTHON := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: demo test test-fast test-browser setup clean

setup: $(STAMP)

$(STAMP): pyproject.toml scripts/setup.sh native/pyproject.toml native/CMakeLists.txt native/bvh_native.cpp
	bash scripts/setup.sh $(VENV)
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/tracer render mitsuba_scenes/hexagon_room.xml --output out/hexagon_room.exr \
		--estimator report --direct 16 --indirect 8 --report-depth 2
	$(VENV)/bin/tracer render mitsuba_scenes/hexagon_room.xml --output out/hexagon_room_path.exr \
		--estimator path --spp 64

# pytest, naming the test it was in if a signal killed it (tests/conftest.py records each test as it starts)
PYTEST = rm -f .pytest_cache/last-started; $(PYTHON) -m pytest -q $(1) || { rc=$$?; [ $$rc -le 128 ] || \
	echo "pytest died of signal $$((rc - 128)) in $$(cat .pytest_cache/last-started 2>/dev/null)" >&2; exit $$rc; }

test: $(STAMP)
	@$(call PYTEST,)

# The edit loop: everything but the tests marked slow (statistical comparisons against Mitsuba, the browser, imports).
test-fast: $(STAMP)
	@$(call PYTEST,-m "not slow")

# The report page's viewer in headless Chromium alone (it also runs in `make test`).
test-browser: $(STAMP)
	$(PYTHON) -m pytest -q tests/test_viewer_browser.py

clean:
	rm -rf $(VENV) $(VENV)-peers out .pytest_cache
