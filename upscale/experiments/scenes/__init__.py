"""The scenes' implementations, one module per area; the public functions are
:mod:`upscale.experiments` (by name through :mod:`upscale.experiments.registry`)."""
