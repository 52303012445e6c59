# The two commands of the README. Both install what is missing first (scripts/setup.sh).
.PHONY: setup demo test test-slow references

setup:
	@scripts/setup.sh

demo: setup
	.venv/bin/evalkit doctor
	.venv/bin/evalkit scene info cornell-box
	.venv/bin/evalkit bundles cornell-box --method perfect --directions 32 --out out/demo/perfect.npz
	.venv/bin/evalkit bundles cornell-box --method imperfect --directions 32 --out out/demo/imperfect.npz
	.venv/bin/evalkit render cornell-box --method perfect --bounces 3 --directions 32 --frames 8 --width 128 --height 128 --out out/demo/render-perfect
	.venv/bin/evalkit render cornell-box --method imperfect --bounces 3 --directions 32 --frames 8 --width 128 --height 128 --out out/demo/render-imperfect

test: setup
	.venv/bin/python -m pytest -m "not slow" -q

test-slow: setup
	.venv/bin/python -m pytest -m slow -q

# The small references committed for CI (references/store); about 10 minutes on 2 cores.
CI_REFERENCES = cornell-box furnace
references: setup
	for scene in $(CI_REFERENCES); do for b in 1 3; do \
	  .venv/bin/evalkit reference $$scene --bounces $$b --spp 16384 --width 128 --height 128 --out out/references/$$scene-b$$b || exit 1; \
	done; done
