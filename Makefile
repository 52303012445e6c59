# The two commands of the README. Both install what is missing first (scripts/setup.sh).
.PHONY: setup demo test test-slow

setup:
	@scripts/setup.sh

demo: setup
	.venv/bin/evalkit doctor
	.venv/bin/evalkit scene info cornell-box
	.venv/bin/evalkit bundles cornell-box --method perfect --directions 32 --out out/demo/perfect.npz
	.venv/bin/evalkit bundles cornell-box --method imperfect --directions 32 --out out/demo/imperfect.npz

test: setup
	.venv/bin/python -m pytest -m "not slow" -q

test-slow: setup
	.venv/bin/python -m pytest -m slow -q
