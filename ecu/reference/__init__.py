"""Float64 twins of the firmware's control functions: the same equations and discretisation in
floats, for tests and analysis only (never imported by the firmware path)."""
