# The two commands of the README. Both install what is missing first (scripts/setup.sh).
.PHONY: setup setup-test demo teaser docs test lint test-long test-slow references studies fuzz fuzz-soak check

setup:
	@scripts/setup.sh

setup-test:
	@scripts/setup.sh test

demo: setup
	.venv/bin/evalkit demo --out out/demo

# The README's picture, from the demo's results.
teaser: setup
	.venv/bin/evalkit demo --out out/demo --figure docs/images/teaser.png

# The documentation site into site/ (open site/index.html from the file system), built strictly.
docs: setup-test
	NO_MKDOCS_2_WARNING=1 .venv/bin/mkdocs build --strict

# The linter and formatter first (a second's work), then the suite in TEST_WORKERS processes
# (pytest-xdist): a test spends much of its time in one thread (Python, Mitsuba, Embree), so two
# processes keep both cores of a small machine busy.
TEST_WORKERS = 2
test: setup-test lint
	.venv/bin/python -m pytest -m "not slow and not long" -q -n $(TEST_WORKERS)

# The tests of 10 s or more on 2 cores (converged images, sweeps, the site build, every shader
# variant compiled), which CI runs after make test.
test-long: setup-test
	.venv/bin/python -m pytest -m long -q -n $(TEST_WORKERS)

lint: setup
	.venv/bin/ruff check .
	.venv/bin/ruff format --check .

test-slow: setup-test
	.venv/bin/python -m pytest -m slow -q -n $(TEST_WORKERS)

# The small references committed for CI (references/store); about 10 minutes on 2 cores.
CI_REFERENCES = cornell-box furnace
references: setup
	for scene in $(CI_REFERENCES); do for b in 1 3; do \
	  .venv/bin/evalkit reference $$scene --bounces $$b --spp 16384 --width 128 --height 128 --store references/store --out out/references/$$scene-b$$b || exit 1; \
	done; done

# The shipped studies (studies/*.toml), each into out/studies/<name>/ with its report; resumable.
STUDIES = hole_vs_splat error_vs_time directions poster_table accuracy resolution gloss bidirectional
studies: setup
	for study in $(STUDIES); do .venv/bin/evalkit study studies/$$study.toml || exit 1; done

# Fuzz the importers with fresh random examples, many more than CI's derandomized few.
fuzz: setup
	HYPOTHESIS_PROFILE=fuzz FUZZ_EXAMPLES=2000 .venv/bin/python -m pytest -q tests/test_fuzz_importers.py

# The fuzzers for a set time in worker processes, crashes and hangs counted (default an hour):
# make fuzz-soak SOAK_SECONDS=600. Failing examples are saved in out/fuzz-soak/.
SOAK_SECONDS = 3600
fuzz-soak: setup
	.venv/bin/python tests/fuzz_soak.py --seconds $(SOAK_SECONDS)

# The declared accuracy thresholds (evalkit/thresholds.toml): table, out/check/junit.xml, exit 1 on a regression.
check: setup
	.venv/bin/evalkit check
