"""Samplers: where along each ray a model evaluates its field (nerfacc's split of sampling from rendering).

``base`` is the protocol; ``configs`` each kind's settings (torch-free); ``hierarchical`` (Section 5.2) and
``marching`` (an occupancy grid, Instant-NGP) are the registered kinds (``nerfpipe.nerf.registry.SAMPLERS``),
built on ``sampling`` (Eqs. 2 and 5), ``occupancy`` and ``march``.
"""
