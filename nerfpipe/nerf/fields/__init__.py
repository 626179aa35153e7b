"""Fields: (x, d) -> (rgb, sigma), the part of a model that is learned.

``base`` is the protocol every field answers; ``configs`` holds each kind's settings (torch-free, so that
naming and checking them imports no torch); ``grid``, ``hash``, ``planes`` and ``mlp`` are the registered
kinds (``nerfpipe.nerf.registry.FIELDS``); ``encoding`` is Eq. 4; ``analytic`` fields with known answers.
"""
