"""One module per family of cases; each registers with ``validation.registry.case``."""
