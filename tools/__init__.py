"""User-facing utilities, thin over the packages."""
