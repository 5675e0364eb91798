# The two commands of the README. Each does all set-up first (idempotent).
.PHONY: setup demo test
setup:
	@bash scripts/setup.sh
demo: setup
	@.venv/bin/vtkiosk demo
test: setup
	@.venv/bin/python -m pytest
