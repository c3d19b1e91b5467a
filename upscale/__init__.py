"""upscale: carry atomistic information up to the continuum scale.

Coarse side: the shared particle engine (:mod:`upscale.engine`), the models that run on it
(:mod:`upscale.models`), structure builders (:mod:`upscale.build`) and scenes
(:mod:`upscale.experiments`). The molecular potentials live in the sibling package
:mod:`potentials`.
"""
__version__ = "0.1.0"
