# The two commands of the README. Both install what is missing first (scripts/setup.sh).
.PHONY: setup demo test test-slow

setup:
	@scripts/setup.sh

demo: setup
	.venv/bin/evalkit doctor
	.venv/bin/evalkit scene info cornell-box

test: setup
	.venv/bin/python -m pytest -m "not slow" -q

test-slow: setup
	.venv/bin/python -m pytest -m slow -q
