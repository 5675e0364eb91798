"""The `vtkiosk` command line: one entry point that dispatches to each subsystem lazily."""
