"""The one typed configuration loader (frozen dataclasses from YAML); every package's config module uses it."""
